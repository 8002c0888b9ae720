"""Proficiency metrics of one trajectory — the one ruler for human demos, scripted demos and policy rollouts.

Every function takes plain arrays (tool-tip positions in metres, jaw commands, success flags) so the
metrics do not care what produced the trajectory. Definitions follow the surgical-skill literature
(see ``shared/docs/reference/algorithms.md`` §5): path length is the summed tip displacement (economy of
motion), smoothness is the log dimensionless jerk, a jaw closure is an open→close transition of the jaw
command (a grasp attempt).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from surrol_data.envs.units import CONTROL_PERIOD_S


@dataclass(frozen=True)
class Proficiency:
    success: bool              # success at any step
    final_success: bool        # success at the last step
    steps: int                 # actions taken
    steps_to_success: int      # first step (1-based) with success, -1 if never
    time_to_success_s: float   # steps_to_success × control period, nan if never
    path_length_cm: float      # tool-tip path up to success (whole episode if never), all arms summed
    path_length_full_cm: float # tool-tip path over the whole episode
    jaw_closures: int          # open→close transitions of the jaw command
    clutch_uses: int           # rising edges of the clutch flag
    log_dimensionless_jerk: float  # higher = smoother; nan when the tip did not move
    idle_fraction: float       # fraction of steps with tip speed < 1 mm/s

    def as_dict(self) -> dict:
        return asdict(self)


def steps_to_success(success: np.ndarray) -> int:
    """1-based index of the first successful step, -1 if none."""
    hits = np.flatnonzero(np.asarray(success, bool))
    return int(hits[0]) + 1 if len(hits) else -1


def path_length_m(tip_position: np.ndarray) -> float:
    """Summed displacement of every arm's tip. ``tip_position`` is (N, 3) or (N, n_arms, 3), metres."""
    p = np.asarray(tip_position, np.float64)
    if p.ndim == 2:
        p = p[:, None, :]
    if len(p) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(p, axis=0), axis=-1).sum())


def jaw_closures(jaw_command: np.ndarray) -> int:
    """Open→close transitions of a jaw command (< 0 means close), summed over arms. The jaw starts open."""
    closed = np.asarray(jaw_command, np.float64) < 0
    if closed.ndim == 1:
        closed = closed[:, None]
    padded = np.concatenate([np.zeros((1, closed.shape[1]), bool), closed], axis=0)
    return int(np.sum(~padded[:-1] & padded[1:]))


def rising_edges(flag: np.ndarray) -> int:
    f = np.concatenate([[False], np.asarray(flag, bool)])
    return int(np.sum(~f[:-1] & f[1:]))


def log_dimensionless_jerk(tip_position: np.ndarray, dt: float = CONTROL_PERIOD_S) -> float:
    """LDLJ = −ln(T⁵/L² · ∫‖jerk‖² dt) of the (first arm's) tip path; nan when too short or still."""
    p = np.asarray(tip_position, np.float64)
    if p.ndim == 3:
        p = p[:, 0, :]
    if len(p) < 5:
        return float("nan")
    length = float(np.linalg.norm(np.diff(p, axis=0), axis=-1).sum())
    if length < 1e-9:
        return float("nan")
    jerk = np.diff(p, n=3, axis=0) / dt**3
    duration = (len(p) - 1) * dt
    integral = float(np.sum(np.sum(jerk**2, axis=-1)) * dt)
    if integral <= 0:
        return float("nan")
    return float(-np.log(duration**5 / length**2 * integral))


def idle_fraction(tip_position: np.ndarray, dt: float = CONTROL_PERIOD_S, threshold_m_s: float = 1e-3) -> float:
    p = np.asarray(tip_position, np.float64)
    if p.ndim == 2:
        p = p[:, None, :]
    if len(p) < 2:
        return 1.0
    speed = np.linalg.norm(np.diff(p, axis=0), axis=-1).max(axis=1) / dt
    return float(np.mean(speed < threshold_m_s))


def proficiency(tip_position: np.ndarray, success: np.ndarray, jaw_command: np.ndarray | None = None,
                clutch: np.ndarray | None = None, dt: float = CONTROL_PERIOD_S) -> Proficiency:
    """All metrics of one trajectory: ``tip_position`` has one more row than ``success`` (the reset pose)."""
    success = np.asarray(success, bool)
    tip = np.asarray(tip_position, np.float64)
    n = len(success)
    k = steps_to_success(success)
    upto = tip[: k + 1] if k > 0 else tip
    return Proficiency(
        success=bool(success.any()),
        final_success=bool(success[-1]) if n else False,
        steps=n,
        steps_to_success=k,
        time_to_success_s=k * dt if k > 0 else float("nan"),
        path_length_cm=100.0 * path_length_m(upto),
        path_length_full_cm=100.0 * path_length_m(tip),
        jaw_closures=jaw_closures(jaw_command) if jaw_command is not None and len(jaw_command) else 0,
        clutch_uses=rising_edges(clutch) if clutch is not None else 0,
        log_dimensionless_jerk=log_dimensionless_jerk(upto, dt),
        idle_fraction=idle_fraction(tip, dt),
    )


def trajectory_proficiency(traj) -> Proficiency:
    """Metrics of a :class:`surrol_data.datasets.trajectory.Trajectory` (jaw command = last action dim per arm)."""
    act = np.asarray(traj.action)
    n_arms = traj.tip_position.shape[1]
    jaw_cmd = act.reshape(len(act), n_arms, -1)[:, :, -1] if act.size and act.shape[1] % 5 == 0 else None
    return proficiency(traj.tip_position, traj.success, jaw_cmd, traj.flags.get("clutch"))


def summarize(results: list[Proficiency]) -> dict:
    """Aggregate over episodes: success rate, mean steps to complete and path length over successful ones."""
    if not results:
        return {"episodes": 0, "success_rate": float("nan"), "final_success_rate": float("nan"),
                "mean_steps_to_success": float("nan"), "mean_path_length_cm": float("nan"),
                "mean_log_dimensionless_jerk": float("nan"), "mean_jaw_closures": float("nan")}
    ok = [r for r in results if r.success]

    def mean(values):
        values = [v for v in values if np.isfinite(v)]
        return float(np.mean(values)) if values else float("nan")

    return {
        "episodes": len(results),
        "success_rate": float(np.mean([r.success for r in results])),
        "final_success_rate": float(np.mean([r.final_success for r in results])),
        "mean_steps_to_success": mean([r.steps_to_success for r in ok]),
        "mean_path_length_cm": mean([r.path_length_cm for r in ok]),
        "mean_log_dimensionless_jerk": mean([r.log_dimensionless_jerk for r in ok]),
        "mean_jaw_closures": mean([r.jaw_closures for r in results]),
    }

"""Proficiency metrics of one trajectory — the one ruler for human demos, scripted demos and policy rollouts.

Every function takes plain arrays (tool-tip positions in metres, jaw commands, per-step event flags) so the
metrics do not care what produced the trajectory. Definitions follow the surgical-skill literature
(``shared/docs/reference/algorithms.md`` §5):

* success is reported twice, always labelled: at any step and at the final step;
* economy of motion is the summed tip displacement (per arm, and summed over arms), angular economy the summed
  absolute change of the tip's rotation angles;
* a jaw closure is an open→close transition of the jaw command (a grasp attempt); a failed grasp is a closure
  during which the arm never held the object; a drop is a hold that ends while the jaw is still commanded
  closed and the task is not yet done; a collision is the onset of a contact with a non-target body;
* idle time is the time spent in stretches of at least ``IDLE_MIN_S`` with tip speed below ``IDLE_SPEED_M_S``;
* smoothness is the log dimensionless jerk (LDLJ) and the spectral arc length (SPARC) of the speed profile.
  They are computed from the device trace at the device's own rate when there is one: at 5 Hz env frames the
  8–12 Hz tremor of a human hand aliases, and only the device samples show it.

Counts that need a record the trajectory does not carry (grasp state, collisions) are ``nan``, never a guessed 0.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from surrol_data.envs.units import CONTROL_PERIOD_S

# Idle: slower than 2 mm/s for at least 1 s. A still hand drifts well under 2 mm/s; the slowest deliberate
# approach of the simulated operators and the oracle (0.4 cm per 0.2 s step = 2 cm/s) is ten times faster.
IDLE_SPEED_M_S = 0.002
IDLE_MIN_S = 1.0
# SPARC (Balasubramanian et al. 2015): spectrum up to 10 Hz, cut where the normalised magnitude drops below 0.05,
# zero-padded by 2**4.
SPARC_MAX_FREQUENCY_HZ = 10.0
SPARC_AMPLITUDE_THRESHOLD = 0.05
SPARC_PAD_LEVEL = 4


@dataclass(frozen=True)
class Proficiency:
    success: bool              # success at any step
    final_success: bool        # success at the last step
    steps: int                 # actions taken
    steps_to_success: int      # first step (1-based) with success, -1 if never
    time_to_success_s: float   # steps_to_success × control period, nan if never
    path_length_cm: float      # tool-tip path up to success (whole episode if never), all arms summed
    path_length_full_cm: float # tool-tip path over the whole episode
    path_length_arm1_cm: float  # path up to success of the first arm
    path_length_arm2_cm: float  # ... of the second arm (nan for one-arm tasks)
    angular_economy_rad: float  # summed |Δ angle| of the tip rotation up to success (nan if not recorded)
    jaw_closures: int          # open→close transitions of the jaw command
    failed_grasps: float       # closures that never held the object (nan if the grasp state was not recorded)
    drops: float               # holds that ended with the jaw still closed before success (nan if not recorded)
    collisions: float          # contact onsets with non-target bodies (nan if not recorded)
    clutch_uses: int           # rising edges of the clutch flag
    idle_time_s: float         # time in idle stretches (see IDLE_SPEED_M_S, IDLE_MIN_S)
    idle_fraction: float       # fraction of steps with tip speed < 1 mm/s
    log_dimensionless_jerk: float  # higher = smoother; nan when the tip did not move
    sparc: float               # spectral arc length, higher (closer to 0) = smoother; nan when still
    smoothness_source: str     # "device" (trace at the device's rate) or "tip" (env frames)

    def as_dict(self) -> dict:
        return asdict(self)


# ---------------------------------------------------------------------------------------------- time and success
def steps_to_success(success: np.ndarray) -> int:
    """1-based index of the first successful step, -1 if none."""
    hits = np.flatnonzero(np.asarray(success, bool))
    return int(hits[0]) + 1 if len(hits) else -1


# ---------------------------------------------------------------------------------------------- economy of motion
def _per_arm(tip_position: np.ndarray) -> np.ndarray:
    p = np.asarray(tip_position, np.float64)
    return p[:, None, :] if p.ndim == 2 else p


def path_length_per_arm_m(tip_position: np.ndarray) -> np.ndarray:
    """Summed displacement of each arm's tip, (n_arms,). ``tip_position`` is (N, 3) or (N, n_arms, 3), metres."""
    p = _per_arm(tip_position)
    if len(p) < 2:
        return np.zeros(p.shape[1])
    return np.linalg.norm(np.diff(p, axis=0), axis=-1).sum(axis=0)


def path_length_m(tip_position: np.ndarray) -> float:
    """Summed displacement of every arm's tip. ``tip_position`` is (N, 3) or (N, n_arms, 3), metres."""
    return float(path_length_per_arm_m(tip_position).sum())


def angular_economy_rad(angles: np.ndarray) -> float:
    """Summed absolute change of rotation angles (N, k) or (N, n_arms, k), each step's change wrapped to (−π, π]."""
    a = np.asarray(angles, np.float64)
    if len(a) < 2:
        return 0.0
    d = np.diff(a, axis=0)
    return float(np.abs((d + np.pi) % (2 * np.pi) - np.pi).sum())


# ---------------------------------------------------------------------------------------------- events
def _columns(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    return x[:, None] if x.ndim == 1 else x


def rising_edges(flag: np.ndarray) -> int:
    """Off→on transitions of a flag (T,) or (T, n), summed over columns; the flag starts off."""
    f = _columns(np.asarray(flag, bool))
    padded = np.concatenate([np.zeros((1, f.shape[1]), bool), f], axis=0)
    return int(np.sum(~padded[:-1] & padded[1:]))


def jaw_closures(jaw_command: np.ndarray) -> int:
    """Open→close transitions of a jaw command (< 0 means close), summed over arms. The jaw starts open."""
    return rising_edges(np.asarray(jaw_command, np.float64) < 0)


def failed_grasps(jaw_command: np.ndarray, grasped: np.ndarray) -> int:
    """Closures (per arm) during which that arm never held the object. Both arrays are (T,) or (T, n_arms);
    ``grasped[t]`` is the grasp state after action ``t``."""
    closed = _columns(np.asarray(jaw_command, np.float64) < 0)
    held = _columns(np.asarray(grasped, bool))
    failed = 0
    for arm in range(closed.shape[1]):
        start = None
        for t in range(len(closed) + 1):
            is_closed = t < len(closed) and closed[t, arm]
            if is_closed and start is None:
                start = t
            elif not is_closed and start is not None:
                failed += not held[start:t, arm].any()
                start = None
    return failed


def first_grasp_failed(jaw_command: np.ndarray, grasped: np.ndarray) -> bool | None:
    """Whether the first closure of the jaw (any arm) held nothing; None when the jaw never closed. The paper's
    qualitative finding is about what a policy does next: retry (recover) or stall."""
    closed = _columns(np.asarray(jaw_command, np.float64) < 0).any(axis=1)
    held = _columns(np.asarray(grasped, bool)).any(axis=1)
    if not closed.any():
        return None
    start = int(np.argmax(closed))
    end = start + int(np.argmax(~closed[start:])) if (~closed[start:]).any() else len(closed)
    return not bool(held[start:end].any())


def drops(jaw_command: np.ndarray, grasped: np.ndarray, success: np.ndarray) -> int:
    """Holds that end while the jaw is still commanded closed and before the task succeeded (per arm, summed).

    A hold that ends because the operator opened the jaw is a release, not a drop; an object lost after
    success does not count (the FLS convention: penalties apply before completion)."""
    closed = _columns(np.asarray(jaw_command, np.float64) < 0)
    held = _columns(np.asarray(grasped, bool))
    done = np.maximum.accumulate(np.asarray(success, bool))
    ended = held[:-1] & ~held[1:]                       # hold lost after action t+1
    lost = ended & closed[1:] & ~done[1:, None]
    return int(lost.sum())


# ---------------------------------------------------------------------------------------------- idle time
def idle_fraction(tip_position: np.ndarray, dt: float = CONTROL_PERIOD_S, threshold_m_s: float = 1e-3) -> float:
    p = _per_arm(tip_position)
    if len(p) < 2:
        return 1.0
    speed = np.linalg.norm(np.diff(p, axis=0), axis=-1).max(axis=1) / dt
    return float(np.mean(speed < threshold_m_s))


def idle_time_s(tip_position: np.ndarray, dt: float = CONTROL_PERIOD_S, speed_m_s: float = IDLE_SPEED_M_S,
                min_duration_s: float = IDLE_MIN_S) -> float:
    """Time spent in stretches of at least ``min_duration_s`` in which every arm's tip moves slower than
    ``speed_m_s``."""
    p = _per_arm(tip_position)
    if len(p) < 2:
        return 0.0
    slow = np.linalg.norm(np.diff(p, axis=0), axis=-1).max(axis=1) / dt < speed_m_s
    total, run = 0, 0
    for s in np.append(slow, False):
        if s:
            run += 1
            continue
        if run * dt >= min_duration_s - 1e-9:
            total += run
        run = 0
    return total * dt


# ---------------------------------------------------------------------------------------------- smoothness
def _first_arm(positions: np.ndarray) -> np.ndarray:
    p = np.asarray(positions, np.float64)
    return p[:, 0, :] if p.ndim == 3 else p


def log_dimensionless_jerk(positions: np.ndarray, dt: float = CONTROL_PERIOD_S) -> float:
    """LDLJ = −ln(T⁵/L² · ∫‖jerk‖² dt) of a path sampled every ``dt`` (the first arm's); nan when too short
    or still. Scale-free: the same shape in millimetres or metres gives the same value."""
    p = _first_arm(positions)
    if len(p) < 5:
        return float("nan")
    length = float(np.linalg.norm(np.diff(p, axis=0), axis=-1).sum())
    if length < 1e-12:
        return float("nan")
    jerk = np.diff(p, n=3, axis=0) / dt**3
    duration = (len(p) - 1) * dt
    integral = float(np.sum(np.sum(jerk**2, axis=-1)) * dt)
    if integral <= 0:
        return float("nan")
    return float(-np.log(duration**5 / length**2 * integral))


def sparc(positions: np.ndarray, dt: float = CONTROL_PERIOD_S) -> float:
    """Spectral arc length of the speed profile of a path sampled every ``dt`` (the first arm's).

    The speed's Fourier magnitude, normalised by its value at 0 Hz, is followed from 0 Hz up to the highest
    frequency (≤ 10 Hz and ≤ Nyquist) where it still exceeds 0.05; SPARC is minus the length of that curve with
    frequency normalised by the cut-off. A single minimum-jerk movement scores −1.41; tremor and stop-and-go
    sub-movements add spectral wiggles and make it more negative. nan when the tip did not move."""
    p = _first_arm(positions)
    if len(p) < 3:
        return float("nan")
    speed = np.linalg.norm(np.diff(p, axis=0), axis=-1) / dt
    if speed.max() <= 1e-12:
        return float("nan")
    n_fft = int(2 ** (np.ceil(np.log2(len(speed))) + SPARC_PAD_LEVEL))
    freq = np.fft.rfftfreq(n_fft, dt)
    magnitude = np.abs(np.fft.rfft(speed, n_fft))
    magnitude /= magnitude.max()
    in_band = freq <= min(SPARC_MAX_FREQUENCY_HZ, 0.5 / dt)
    freq, magnitude = freq[in_band], magnitude[in_band]
    above = np.flatnonzero(magnitude >= SPARC_AMPLITUDE_THRESHOLD)
    cut = above[-1] + 1 if len(above) else len(freq)
    freq, magnitude = freq[:cut], magnitude[:cut]
    if len(freq) < 2:
        return 0.0
    d_freq = np.diff(freq) / (freq[-1] - freq[0])
    return float(-np.sum(np.sqrt(d_freq**2 + np.diff(magnitude) ** 2)))


@dataclass(frozen=True)
class DeviceTrace:
    """A device's own samples (e.g. the Touch stylus at 100–1000 Hz): positions (M, 3) in any length unit and
    times (M,) in seconds. Smoothness is measured on it when present."""
    position: np.ndarray
    t: np.ndarray

    def resampled(self) -> tuple[np.ndarray, float]:
        """Positions on a uniform time grid at the trace's median rate (device clocks jitter)."""
        t = np.asarray(self.t, np.float64)
        p = np.asarray(self.position, np.float64)
        dt = float(np.median(np.diff(t))) if len(t) > 1 else CONTROL_PERIOD_S
        if dt <= 0:
            raise ValueError("device trace times must increase; got a non-positive median interval")
        grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
        return np.stack([np.interp(grid, t, p[:, k]) for k in range(p.shape[1])], axis=1), dt


# Where a haptic session saved its device's own samples (= surrol_data.collect.devices.trace: not imported, the
# dataset layer sits below the devices): frames (n_devices, T, 8) with x, y, z (mm), gimbals, buttons, t (s).
TRACE_FILE = "meta/device_traces/episode_{:06d}.npz"


def recorded_device_trace(root: str | Path, episode: int) -> DeviceTrace | None:
    """The first device's trace of ``episode`` of the dataset at ``root``, or None where none was recorded."""
    path = Path(root) / TRACE_FILE.format(int(episode))
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        frames = z["frames"][0]
    return DeviceTrace(position=frames[:, :3], t=frames[:, 7])


def smoothness_path(tip_upto_success: np.ndarray, dt: float,
                    device_trace: DeviceTrace | None) -> tuple[np.ndarray, float, str]:
    """The path smoothness (LDLJ, SPARC) is measured on, its sample interval and its name: the device's own trace
    where one holds five samples or more (a person's hand at its own rate), else the tool tip up to success."""
    if device_trace is not None and len(device_trace.t) >= 5:
        return *device_trace.resampled(), "device"
    return tip_upto_success, dt, "tip"


# ---------------------------------------------------------------------------------------------- one trajectory
def proficiency(tip_position: np.ndarray, success: np.ndarray, jaw_command: np.ndarray | None = None,
                clutch: np.ndarray | None = None, dt: float = CONTROL_PERIOD_S, *,
                tip_angles: np.ndarray | None = None, grasped: np.ndarray | None = None,
                collision: np.ndarray | None = None, drop: np.ndarray | None = None,
                device_trace: DeviceTrace | None = None) -> Proficiency:
    """All metrics of one trajectory: ``tip_position`` (and ``tip_angles``) have one more row than ``success``
    (the reset pose first); per-step arrays (``jaw_command``, ``clutch``, ``grasped``, ``collision``, ``drop``)
    have one row per action. ``drop``, when the env reports drop events itself, overrides the drop rule."""
    success = np.asarray(success, bool)
    tip = np.asarray(tip_position, np.float64)
    n = len(success)
    k = steps_to_success(success)
    upto = tip[: k + 1] if k > 0 else tip
    per_arm = 100.0 * path_length_per_arm_m(upto)
    has_jaw = jaw_command is not None and len(jaw_command) == n and n > 0
    smooth_path, smooth_dt, source = smoothness_path(upto, dt, device_trace)
    if drop is not None:
        n_drops = float(rising_edges(drop))
    elif grasped is not None and has_jaw:
        n_drops = float(drops(jaw_command, grasped, success))
    else:
        n_drops = float("nan")
    return Proficiency(
        success=bool(success.any()),
        final_success=bool(success[-1]) if n else False,
        steps=n,
        steps_to_success=k,
        time_to_success_s=k * dt if k > 0 else float("nan"),
        path_length_cm=float(per_arm.sum()),
        path_length_full_cm=100.0 * path_length_m(tip),
        path_length_arm1_cm=float(per_arm[0]),
        path_length_arm2_cm=float(per_arm[1]) if len(per_arm) > 1 else float("nan"),
        angular_economy_rad=(angular_economy_rad(np.asarray(tip_angles)[: len(upto)])
                             if tip_angles is not None else float("nan")),
        jaw_closures=jaw_closures(jaw_command) if has_jaw else 0,
        failed_grasps=float(failed_grasps(jaw_command, grasped)) if grasped is not None and has_jaw else float("nan"),
        drops=n_drops,
        collisions=float(rising_edges(collision)) if collision is not None else float("nan"),
        clutch_uses=rising_edges(clutch) if clutch is not None else 0,
        idle_time_s=idle_time_s(tip, dt),
        idle_fraction=idle_fraction(tip, dt),
        log_dimensionless_jerk=log_dimensionless_jerk(smooth_path, smooth_dt),
        sparc=sparc(smooth_path, smooth_dt),
        smoothness_source=source,
    )


def psm_tip_angles(observation: np.ndarray) -> np.ndarray | None:
    """The tip rotation angles (roll, pitch, yaw relative to tool-down) of each PSM from the env's documented
    observation layout — (T+1, n_arms, 3) — or None for layouts without them (ECM tasks)."""
    obs = np.asarray(observation, np.float64)
    if obs.ndim != 2:
        return None
    if obs.shape[1] in (7, 19):
        return obs[:, None, 3:6]
    if obs.shape[1] == 35:
        return np.stack([obs[:, 3:6], obs[:, 10:13]], axis=1)
    return None


def trajectory_proficiency(traj, device_trace: DeviceTrace | None = None) -> Proficiency:
    """Metrics of a :class:`surrol_data.datasets.trajectory.Trajectory` (jaw command = last action dim per arm).

    Event records beyond the device flags are read from ``traj.flags`` when a collector or rollout stored them:
    ``grasped`` (T,) or (T, n_arms), ``collision`` and ``drop``."""
    act = np.asarray(traj.action)
    n_arms = traj.tip_position.shape[1]
    jaw_cmd = act.reshape(len(act), n_arms, -1)[:, :, -1] if act.size and act.shape[1] % 5 == 0 else None
    flags = traj.flags
    return proficiency(traj.tip_position, traj.success, jaw_cmd, flags.get("clutch"),
                       tip_angles=psm_tip_angles(traj.observation), grasped=flags.get("grasped"),
                       collision=flags.get("collision"), drop=flags.get("drop"), device_trace=device_trace)


# ---------------------------------------------------------------------------------------------- aggregates
def _finite(values) -> np.ndarray:
    v = np.asarray([float(x) for x in values], np.float64)
    return v[np.isfinite(v)]


def bootstrap_ci(values, confidence: float = 0.95, resamples: int = 2000, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values`` (non-finite values ignored); (nan, nan) when
    fewer than two values. Seeded: the same values give the same interval."""
    v = _finite(values)
    if len(v) < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), size=(resamples, len(v)))].mean(axis=1)
    alpha = (1.0 - confidence) / 2
    return float(np.quantile(means, alpha)), float(np.quantile(means, 1 - alpha))


@dataclass(frozen=True)
class Estimate:
    """Mean ± std (sample std, ddof=1) over n values, with a bootstrap 95 % interval of the mean."""
    mean: float
    std: float
    n: int
    ci_low: float
    ci_high: float

    def format(self, digits: int = 1, scale: float = 1.0) -> str:
        """``12.3 ± 1.2`` (``–`` when there is no value), scaled e.g. by 100 for percentages."""
        if self.n == 0:
            return "–"
        if self.n == 1 or not np.isfinite(self.std):
            return f"{self.mean * scale:.{digits}f}"
        return f"{self.mean * scale:.{digits}f} ± {self.std * scale:.{digits}f}"


def estimate(values, seed: int = 0) -> Estimate:
    """Mean, std and bootstrap interval of finite ``values`` (e.g. one success rate per training seed)."""
    v = _finite(values)
    if len(v) == 0:
        return Estimate(float("nan"), float("nan"), 0, float("nan"), float("nan"))
    low, high = bootstrap_ci(v, seed=seed)
    return Estimate(float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else float("nan"), len(v), low, high)


def summarize(results: list[Proficiency]) -> dict:
    """Aggregate over episodes: success rates (any-step and final-step), and mean completion steps, economy and
    smoothness over the successful episodes; event counts over all episodes."""
    def mean(values):
        v = _finite(values)
        return float(v.mean()) if len(v) else float("nan")

    ok = [r for r in results if r.success]
    return {
        "episodes": len(results),
        "success_rate": mean([r.success for r in results]),
        "final_success_rate": mean([r.final_success for r in results]),
        "mean_steps_to_success": mean([r.steps_to_success for r in ok]),
        "mean_time_to_success_s": mean([r.time_to_success_s for r in ok]),
        "mean_path_length_cm": mean([r.path_length_cm for r in ok]),
        "mean_angular_economy_rad": mean([r.angular_economy_rad for r in ok]),
        "mean_log_dimensionless_jerk": mean([r.log_dimensionless_jerk for r in ok]),
        "mean_sparc": mean([r.sparc for r in ok]),
        "mean_jaw_closures": mean([r.jaw_closures for r in results]),
        "mean_failed_grasps": mean([r.failed_grasps for r in results]),
        "mean_drops": mean([r.drops for r in results]),
        "mean_collisions": mean([r.collisions for r in results]),
        "mean_clutch_uses": mean([r.clutch_uses for r in results]),
        "mean_idle_time_s": mean([r.idle_time_s for r in results]),
    }

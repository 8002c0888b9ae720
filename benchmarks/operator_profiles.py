"""Simulated operators against the script oracle on NeedlePick, and the errors they make beside people's.

Usage: ``uv run python benchmarks/operator_profiles.py [--identities 4] [--episodes 25] [--horizon 300]``

Each profile (expert, novice) runs ``identities`` operators × ``episodes`` seeded attempts of up to 300 steps (twice
the paper's 150-step human recordings: the literature's times and paths are of finished tasks, and a horizon that cut
the slow novices' attempts short would keep only their quickest, shortest ones) through the real device mapping into
the env; the oracle runs the same seeds. Two tables:

* **skill**: success, steps to success, path (means ± sd over the successful attempts), smoothness, clutch uses;
* **calibration**: per attempt, novice and expert beside published human data from robotic surgical simulators,
  dry-lab and console recordings (:data:`LITERATURE`), and the novice/expert ratio beside the sources' range. Time
  and path are over the successful attempts; the error counts per attempt over all of them:

  - *failed grasps*: jaw closures that never held the needle (``datasets/metrics.failed_grasps``);
  - *drops*: holds of the needle lost before the task succeeded, whatever the jaw did (a lapse of the grip opens it);
  - *collisions*: onsets of the tool's contact with the tray or its pad made descending faster than
    :data:`STRIKE_SPEED_MM_S` (a strike; a grasp settles the open jaw onto the pad at the end of a movement, slower
    than that), or pressing with more than :data:`COLLISION_FORCE_N` (which the arm's force limits keep it under);
  - *out of view*: onsets of the tool tip leaving the endoscope image;
  - *idle*: seconds in idle stretches (``datasets/metrics.idle_time_s``).

The literature's figures are other tasks' (suturing, ring transfer, clinical steps): what carries over to NeedlePick
is the ratio novice/expert, which the last column checks against the sources' range.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.haptic_source import control_period_s as task_period_s
from surrol_data.collect.mapping import ActionMapper, MappingSettings, view_to_action
from surrol_data.collect.operator import SimulatedOperator
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.trajectory import TrajectoryBuilder
from surrol_data.envs.camera import camera_axes, project
from surrol_data.envs.physics import pb
from surrol_data.evaluation.rollout import ORACLE, rollout

FIRST_SEED = 1000
COLLISION_FORCE_N = 3.0
# A contact with the tray made at more than this descent speed is a strike, not a grasp settling onto the pad: the
# simulated operators' grasps land at ≤ 5 mm/s (≤ 1 mm a step), an overshooting descent at 8–28 mm/s.
STRIKE_SPEED_MM_S = 7.5
BOOTSTRAP_RESAMPLES = 4000


@dataclass(frozen=True)
class Source:
    metric: str
    novice: str          # the source's figure for novices, as published
    expert: str
    ratio: tuple[float, float] | None   # novice/expert over the source's tasks or groups (low, high); None: no figure
    source: str


# Published novice and expert figures (robotic surgical simulators, dry lab, the da Vinci console); see
# docs/teleoperation.md#errors-people-make for what each measured.
LITERATURE = {
    "time": Source("time to complete", "181–197 s; 15.5–26.8 min", "107–154 s; 5.7–10.6 min", (1.3, 2.8),
                   "Foell et al. 2013, Can Urol Assoc J 7:430 (dry lab, ring transfer and needle passing, robotic "
                   "novices before vs after a basic skills course: 1.3–1.7); Hung et al. 2018, J Urol 199:296 "
                   "(da Vinci console recordings, 4 prostatectomy steps, novice vs expert surgeons: 1.8–2.8)"),
    "path": Source("instrument path", "20.9–45.2 m", "9.9–25 m", (1.4, 2.1),
                   "Hung et al. 2018 (as above); Judkins et al. 2009, Surg Endosc 23:590 (da Vinci dry lab: "
                   "distance larger for novices, p < 0.05)"),
    "idle": Source("instrument idle time", "32–246 s", "11–29 s", (1.3, 8.5), "Hung et al. 2018 (as above)"),
    "failed_grasps": Source("errors in gestures", "2.84 / knot", "1.00 / knot", (1.7, 5.5),
                            "Vedula et al. 2016, PLoS One 11:e0149174 (da Vinci dry-lab knot tying; the range is "
                            "that of the two 95 % intervals' bounds: 2.30–3.37 over 0.61–1.39)"),
    "drops": Source("errors (drops, out of view)", "3.5–4.5 / task", "1.3–1.8 / task", (2.5, 2.7),
                    "Foell et al. 2013 (as above)"),
    "collisions": Source("instrument collisions", "scored", "scored", None,
                         "da Vinci Skills Simulator metric (Kelly et al. 2012, Urology 79:1068; Hung et al. 2011, "
                         "J Urol 186:1019): experts fewer; no per-group figure retrieved"),
    "out_of_view": Source("instruments out of view", "scored", "scored", None, "as collisions"),
}


def _tray_bodies(env) -> list[int]:
    cid = env.client._client
    bodies = [pb.getBodyUniqueId(i, physicsClientId=cid) for i in range(pb.getNumBodies(physicsClientId=cid))]
    return [b for b in bodies if b not in (env.psm.body, env.object_id)]


def _onsets(flag: list[bool]) -> int:
    f = np.asarray(flag, bool)
    return int(f[0] + np.sum(f[1:] & ~f[:-1])) if len(f) else 0


def operator_episode(env, operator: SimulatedOperator, seed: int, horizon: int) -> dict:
    """One attempt, recorded as a session records it, with the errors the recording does not hold (collisions,
    out of view, drops of any kind) read from the scene as it runs."""
    task = env.unwrapped
    mapper = ActionMapper(operator.mapping)
    obs, info = env.reset(seed=seed)
    cid = task.client._client
    tray = _tray_bodies(task)
    builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
    colliding, outside, held, success = [], [], [], []
    touching_before, tip_before = False, np.asarray(obs["observation"][:3], np.float64)
    period_s = task_period_s(task)
    for _ in range(horizon):
        operator.observe(obs, info)
        step = mapper(operator.read(), view_to_action(task))
        obs, reward, terminated, truncated, info = env.step(step.arm)
        builder.add(step.arm, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    flags={"clutch": step.clutch, "jaw_button": step.jaw_button}, info=info)
        forces = [c[9] for b in tray for c in pb.getContactPoints(task.psm.body, b, physicsClientId=cid)]
        tip = np.asarray(obs["observation"][:3], np.float64)
        descent_mm_s = (tip_before[2] - tip[2]) * 1000.0 / period_s
        struck = bool(forces) and not touching_before and descent_mm_s > STRIKE_SPEED_MM_S
        colliding.append(struck or max(forces, default=0.0) > COLLISION_FORCE_N)
        touching_before, tip_before = bool(forces), tip
        x, y, depth = project(camera_axes(task.endoscope_pose()), obs["observation"][:3])
        outside.append(not (abs(x) <= 1.0 and abs(y) <= 1.0 and depth > 0))
        held.append(bool(info["grasped"]))
        success.append(bool(info["is_success"]))
        if terminated or truncated or info["is_success"]:   # (a session ends at success)
            break
    score = trajectory_proficiency(builder.build())
    done = np.maximum.accumulate(np.asarray(success, bool))
    h = np.asarray(held, bool)
    drops = int(np.sum(h[:-1] & ~h[1:] & ~done[1:]))
    return {"score": score, "collisions": _onsets(colliding), "out_of_view": _onsets(outside), "drops": drops}


def run_profiles(identities: int, episodes: int, horizon: int, suffix: str = "",
                 advance=lambda: None) -> dict[str, list[dict]]:
    """Per skill (``expert``, ``novice``; ``suffix`` "_matched" for the study's profiles): ``identities`` operators ×
    ``episodes`` attempts each, operator ``i``'s on seeds ``FIRST_SEED + i * episodes`` on."""
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=horizon)
    runs: dict[str, list[dict]] = {}
    for skill in ("expert", "novice"):
        runs[skill] = []
        for i in range(identities):
            op = SimulatedOperator(env.unwrapped, skill + suffix, f"{skill}-{i}", MappingSettings(), 0)
            op.connect()
            for k in range(episodes):
                runs[skill].append(operator_episode(env, op, FIRST_SEED + i * episodes + k, horizon))
                advance()
    env.close()
    return runs


def summarise(name: str, scores: list) -> list[str]:
    ok = [s for s in scores if s.success]

    def stat(field, fmt="{:.1f}"):
        v = np.array([getattr(s, field) for s in ok], np.float64)
        return "—" if not len(v) else f"{fmt.format(v.mean())} ± {fmt.format(v.std())}"

    ldlj = np.mean([s.log_dimensionless_jerk for s in ok]) if ok else float("nan")
    return [name, f"{len(ok)}/{len(scores)}", stat("steps_to_success"), stat("path_length_cm"), f"{ldlj:.1f}",
            f"{np.mean([s.clutch_uses for s in scores]):.1f}"]


def _values(episodes: list[dict], metric: str) -> np.ndarray:
    """One value per attempt (time and path: per successful attempt)."""
    if metric in ("time", "path"):
        field = "time_to_success_s" if metric == "time" else "path_length_cm"
        return np.array([getattr(e["score"], field) for e in episodes if e["score"].success], np.float64)
    if metric in ("failed_grasps", "idle"):
        field = "failed_grasps" if metric == "failed_grasps" else "idle_time_s"
        return np.array([getattr(e["score"], field) for e in episodes], np.float64)
    return np.array([e[metric] for e in episodes], np.float64)


def _ratio(novice: float, expert: float) -> float:
    return novice / expert if expert > 0 else (np.inf if novice > 0 else float("nan"))


def ratio_interval(novice: np.ndarray, expert: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES) -> tuple[float, float]:
    """The 95 % bootstrap interval of mean(novice) / mean(expert), the attempts of each skill resampled apart: the
    error counts are a few dozen events per hundred attempts, so their ratio is uncertain by tens of per cent."""
    rng = np.random.default_rng(0)
    n = rng.choice(novice, (resamples, len(novice))).mean(1)
    e = rng.choice(expert, (resamples, len(expert))).mean(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(e > 0, n / np.where(e > 0, e, 1.0), np.inf)
    return float(np.quantile(r, 0.025)), float(np.quantile(r, 0.975))


def calibration(runs: dict[str, list[dict]]) -> list[dict]:
    """Per metric: ours for novice and expert, their ratio with its 95 % interval, and the literature's."""
    rows = []
    units = {"time": "s", "path": "cm", "idle": "s"}
    for metric, lit in LITERATURE.items():
        nv, ev = _values(runs["novice"], metric), _values(runs["expert"], metric)
        novice, expert = float(nv.mean()), float(ev.mean())
        ratio = _ratio(novice, expert)
        low, high = ratio_interval(nv, ev) if expert > 0 else (float("nan"), float("nan"))
        if lit.ratio is None:
            within = "n/a"
        elif lit.ratio[0] <= ratio <= lit.ratio[1]:
            within = "yes"
        else:
            within = "interval overlaps" if low <= lit.ratio[1] and high >= lit.ratio[0] else "no"
        rows.append({"metric": metric, "unit": units.get(metric, "/ attempt"), "novice": novice, "expert": expert,
                     "ratio": ratio, "interval": (low, high), "lit": lit, "within": within})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--identities", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=25, help="attempts per identity")
    parser.add_argument("--horizon", type=int, default=300)
    parser.add_argument("--matched", action="store_true",
                        help="the matched profiles (expert_matched, novice_matched: the study's demo sources)")
    args = parser.parse_args()
    suffix = "_matched" if args.matched else ""
    n = args.identities * args.episodes
    with Progress(transient=True) as progress:
        bar = progress.add_task("episodes", total=3 * n)
        oracle = []
        env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=args.horizon)
        for s in range(FIRST_SEED, FIRST_SEED + n):
            oracle.append(trajectory_proficiency(rollout(env, ORACLE, s)))
            progress.advance(bar)
        env.close()
        runs = run_profiles(args.identities, args.episodes, args.horizon, suffix, lambda: progress.advance(bar))
    rows = [summarise("script oracle", oracle)] + [summarise(skill + suffix, [e["score"] for e in runs[skill]])
                                                   for skill in ("expert", "novice")]
    console = Console(width=200)
    table = Table(title=f"simulated operators on NeedlePick ({args.horizon}-step attempts, {args.identities} "
                        f"identities × {args.episodes} episodes per profile)")
    for col in ("source", "success", "steps to success", "path (cm)", "smoothness (LDLJ)", "clutch uses / ep"):
        table.add_column(col, justify="left" if col == "source" else "right")
    for row in rows:
        table.add_row(*row)
    console.print(table)
    calib = Table(title=f"errors and effort beside people's ({n} attempts per skill; time and path over successes)")
    for col in ("metric", "novice", "expert", "ratio", "95 % interval", "literature: novice", "expert", "ratio range",
                "within", "source"):
        calib.add_column(col)
    for r in calibration(runs):
        lit = r["lit"]
        low, high = r["interval"]
        calib.add_row(f"{r['metric']} ({r['unit']})", f"{r['novice']:.2f}", f"{r['expert']:.2f}", f"{r['ratio']:.2f}",
                      "—" if np.isnan(low) else f"{low:.2f}–{high:.2f}",
                      lit.novice, lit.expert, "—" if lit.ratio is None else f"{lit.ratio[0]:g}–{lit.ratio[1]:g}",
                      r["within"], lit.source)
    console.print(calib)


if __name__ == "__main__":
    main()

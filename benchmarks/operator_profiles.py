"""Simulated operators against the script oracle on NeedlePick, and the errors they make beside people's.

Usage: ``uv run python benchmarks/operator_profiles.py [--identities 4] [--episodes 25] [--horizon 150]``

Each profile (expert, novice) runs ``identities`` operators × ``episodes`` seeded 150-step attempts (the paper's
human recording length) through the real device mapping into the env; the oracle runs the same seeds. Two tables:

* **skill**: success, steps to success, path (means ± sd over the successful attempts), smoothness, clutch uses;
* **calibration**: per attempt, novice and expert beside published human data from robotic surgical simulators,
  dry-lab and console recordings (:data:`LITERATURE`), and the novice/expert ratio beside the sources' range. Time
  and path are over the successful attempts; the error counts per attempt over all of them:

  - *failed grasps*: jaw closures that never held the needle (``datasets/metrics.failed_grasps``);
  - *drops*: holds of the needle lost before the task succeeded, whatever the jaw did (a lapse of the grip opens it);
  - *collisions*: onsets of the tool pressing on the tray or its pad with more than :data:`COLLISION_FORCE_N` (the
    grasp presses the open jaw gently onto the pad; a harder push is what the simulators score as excessive force or a
    collision);
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
from surrol_data.collect.mapping import ActionMapper, MappingSettings, view_to_action
from surrol_data.collect.operator import SimulatedOperator
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.trajectory import TrajectoryBuilder
from surrol_data.envs.camera import camera_axes, project
from surrol_data.envs.physics import pb
from surrol_data.evaluation.rollout import ORACLE, rollout

FIRST_SEED = 1000
COLLISION_FORCE_N = 3.0


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
    pressing, outside, held, success = [], [], [], []
    for _ in range(horizon):
        operator.observe(obs, info)
        step = mapper(operator.read(), view_to_action(task))
        obs, reward, terminated, truncated, info = env.step(step.arm)
        builder.add(step.arm, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    flags={"clutch": step.clutch, "jaw_button": step.jaw_button}, info=info)
        force = max((c[9] for b in tray for c in pb.getContactPoints(task.psm.body, b, physicsClientId=cid)),
                    default=0.0)
        pressing.append(force > COLLISION_FORCE_N)
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
    return {"score": score, "collisions": _onsets(pressing), "out_of_view": _onsets(outside), "drops": drops}


def summarise(name: str, scores: list) -> list[str]:
    ok = [s for s in scores if s.success]

    def stat(field, fmt="{:.1f}"):
        v = np.array([getattr(s, field) for s in ok], np.float64)
        return "—" if not len(v) else f"{fmt.format(v.mean())} ± {fmt.format(v.std())}"

    ldlj = np.mean([s.log_dimensionless_jerk for s in ok]) if ok else float("nan")
    return [name, f"{len(ok)}/{len(scores)}", stat("steps_to_success"), stat("path_length_cm"), f"{ldlj:.1f}",
            f"{np.mean([s.clutch_uses for s in scores]):.1f}"]


def calibration(runs: dict[str, list[dict]]) -> list[dict]:
    """Per metric: ours for novice and expert, their ratio, and the literature's."""
    def ours(skill: str, metric: str) -> float:
        eps = runs[skill]
        if metric in ("time", "path"):
            field = "time_to_success_s" if metric == "time" else "path_length_cm"
            return float(np.mean([getattr(e["score"], field) for e in eps if e["score"].success]))
        if metric in ("failed_grasps", "idle"):
            field = "failed_grasps" if metric == "failed_grasps" else "idle_time_s"
            return float(np.mean([getattr(e["score"], field) for e in eps]))
        return float(np.mean([e[metric] for e in eps]))

    rows = []
    units = {"time": "s", "path": "cm", "idle": "s"}
    for metric, lit in LITERATURE.items():
        novice, expert = ours("novice", metric), ours("expert", metric)
        ratio = novice / expert if expert > 0 else (np.inf if novice > 0 else float("nan"))
        within = "n/a" if lit.ratio is None else ("yes" if lit.ratio[0] <= ratio <= lit.ratio[1] else "no")
        rows.append({"metric": metric, "unit": units.get(metric, "/ attempt"), "novice": novice, "expert": expert,
                     "ratio": ratio, "lit": lit, "within": within})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--identities", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=25, help="attempts per identity")
    parser.add_argument("--horizon", type=int, default=150)
    parser.add_argument("--matched", action="store_true",
                        help="the matched profiles (expert_matched, novice_matched: the study's demo sources)")
    args = parser.parse_args()
    suffix = "_matched" if args.matched else ""
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=args.horizon)
    n = args.identities * args.episodes
    seeds = range(FIRST_SEED, FIRST_SEED + n)
    runs: dict[str, list[dict]] = {}
    with Progress(transient=True) as progress:
        bar = progress.add_task("episodes", total=3 * n)
        oracle = []
        for s in seeds:
            oracle.append(trajectory_proficiency(rollout(env, ORACLE, s)))
            progress.advance(bar)
        rows = [summarise("script oracle", oracle)]
        for skill in ("expert", "novice"):
            runs[skill] = []
            for i in range(args.identities):
                op = SimulatedOperator(env.unwrapped, skill + suffix, f"{skill}-{i}", MappingSettings(), 0)
                op.connect()
                for k in range(args.episodes):
                    runs[skill].append(operator_episode(env, op, FIRST_SEED + i * args.episodes + k, args.horizon))
                    progress.advance(bar)
            rows.append(summarise(skill + suffix, [e["score"] for e in runs[skill]]))
    env.close()
    console = Console(width=200)
    table = Table(title=f"simulated operators on NeedlePick ({args.horizon}-step attempts, {args.identities} "
                        f"identities × {args.episodes} episodes per profile)")
    for col in ("source", "success", "steps to success", "path (cm)", "smoothness (LDLJ)", "clutch uses / ep"):
        table.add_column(col, justify="left" if col == "source" else "right")
    for row in rows:
        table.add_row(*row)
    console.print(table)
    calib = Table(title=f"errors and effort beside people's ({n} attempts per skill; time and path over successes)")
    for col in ("metric", "novice", "expert", "ratio", "literature: novice", "expert", "ratio range", "within",
                "source"):
        calib.add_column(col)
    for r in calibration(runs):
        lit = r["lit"]
        calib.add_row(f"{r['metric']} ({r['unit']})", f"{r['novice']:.2f}", f"{r['expert']:.2f}", f"{r['ratio']:.2f}",
                      lit.novice, lit.expert, "—" if lit.ratio is None else f"{lit.ratio[0]:g}–{lit.ratio[1]:g}",
                      r["within"], lit.source)
    console.print(calib)


if __name__ == "__main__":
    main()

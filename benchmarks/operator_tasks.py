"""Simulated operators on every task, through the whole haptic path: success, steps and path per task and skill.

Usage: ``uv run python benchmarks/operator_tasks.py [--episodes 5] [--tasks NeedlePick ...] [--out table.md]``

For each task and skill (``expert``, ``novice``) it records ``episodes`` attempts with
``collect_haptic(device="operator", keep_failures=True)`` (seeds 0, 1, …; the session's default horizon:
3× the registered one in time, or a task's ``HUMAN_PACE_STEPS``, twice that for two-arm tasks; or ``--max-steps``)
into a temporary dataset and reads success, steps to success and tool path back from the episodes' provenance —
the numbers ``surrol-data info`` shows — and where skill shows from the recorded episodes (the proficiency
metrics of ``surrol-data assess``): failed grasps, clutch uses and idle time per episode. The script oracle's row
(same seeds, registered horizon) is the reference (its skill columns are left empty: it runs on after success).
Steps and path are mean ± sd over the successful episodes; the per-episode counts are means over all episodes.
Everything is seeded, so a task's rows do not depend on which other tasks run.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.progress import track
from rich.table import Table

from surrol_data.collect.haptic_source import _human_horizon, collect_haptic
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.reader import DatasetReader
import surrol_data.envs
from surrol_data.evaluation.rollout import ORACLE, rollout

SKILLS = ("expert", "novice")


COLUMNS = ("task", "source", "horizon", "success", "steps to success", "path (cm)", "failed grasps / ep",
           "clutch / ep", "idle (s) / ep")


def _summary(success: np.ndarray, steps: np.ndarray, path: np.ndarray, scores: list | None = None) -> dict:
    ok = success.astype(bool)

    def stat(values):
        v = values[ok]
        return f"{v.mean():.1f} ± {v.std():.1f}" if len(v) else "–"

    def per_episode(field, digits=1):
        values = np.array([getattr(s, field) for s in scores], np.float64) if scores else np.array([])
        values = values[np.isfinite(values)]
        return f"{values.mean():.{digits}f}" if len(values) else "–"

    return {"success": f"{ok.sum()}/{len(ok)}", "steps to success": stat(steps), "path (cm)": stat(path),
            "failed grasps / ep": per_episode("failed_grasps"), "clutch / ep": per_episode("clutch_uses"),
            "idle (s) / ep": per_episode("idle_time_s")}


def oracle_row(task: str, episodes: int) -> dict:
    env = gym.make(surrol_data.envs.env_id(task))
    try:
        scores = [trajectory_proficiency(rollout(env, ORACLE, seed)) for seed in range(episodes)]
        horizon = env.spec.max_episode_steps
    finally:
        env.close()
    return {"horizon": str(horizon), **_summary(np.array([s.success for s in scores]),
                                                np.array([s.steps_to_success for s in scores], float),
                                                np.array([s.path_length_cm for s in scores]))}


def operator_row(task: str, skill: str, episodes: int, workdir: Path, max_steps: int | None = None) -> dict:
    out = workdir / f"{task}_{skill}"
    collect_haptic(task, episodes, out, device="operator", skill=skill, operator_id=f"{skill}-1", seed=0,
                   keep_failures=True, max_attempts=episodes, progress=False, max_steps=max_steps)
    reader = DatasetReader(out)
    ep = reader.episodes
    scores = [trajectory_proficiency(reader.trajectory(i)) for i in range(len(ep))]
    eid = surrol_data.envs.env_id(task)
    horizon = max_steps or _human_horizon(eid, gym.spec(eid).max_episode_steps)
    return {"horizon": str(horizon), **_summary(ep["success"].to_numpy(), ep["steps_to_success"].to_numpy(float),
                                                ep["path_length_cm"].to_numpy(), scores)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--tasks", nargs="*", default=list(surrol_data.envs.TASKS))
    parser.add_argument("--max-steps", type=int, default=None,
                        help="operators' horizon (default: the haptic session's, see collect_haptic)")
    parser.add_argument("--out", type=Path, default=None, help="also write the table as Markdown here")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [(task, who) for task in args.tasks for who in ("script", *SKILLS)]
        for task, who in track(jobs, description="operators"):
            row = (oracle_row(task, args.episodes) if who == "script"
                   else operator_row(task, who, args.episodes, Path(tmp), args.max_steps))
            rows.append({"task": task, "source": who, **row})
    table = Table(title=f"Simulated operators through the haptic path ({args.episodes} episodes each)")
    for col in COLUMNS:
        table.add_column(col)
    for r in rows:
        table.add_row(*(r[c] for c in COLUMNS))
    Console().print(table)
    if args.out:
        lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
        lines += ["| " + " | ".join(r[c] for c in COLUMNS) + " |" for r in rows]
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

"""Collection speed: the env alone against `surrol-data collect`, same task, same seeds, one run each.

Usage: ``uv run python benchmarks/collect_speed.py [--task NeedlePick] [--episodes 200] [--workers 1 2]
[--json FILE]``

Each side runs in a fresh Python process, started by this one, so both pay their own imports:

* **env alone**: ``gym.make`` then, for each seed ``0..A-1`` (``A``: the attempts ``collect`` made, so both roll out
  exactly the same episodes, failures included), :func:`surrol_data.collect.rollout.rollout` with the task's oracle
  — the rollout ``collect`` itself calls, nothing written;
* **collect**: the real ``surrol-data collect --source script`` (the typer app, ``--workers`` as given) into a new
  folder; the moment each ``DatasetRecorder.record`` returns (the episode durable) is taken in the child.

Per side: start-up (process start to the first episode done), the median seconds per episode after it, and the
episodes/s after start-up (episodes 2..N over the time from the first to the last). The ratio is collect's
episodes/s over the env's (the issue's target ≥ 0.8). A state-only ``collect`` imports lerobot (~5 s) and creates
its LeRobot dataset after start-up, in the recording process while the workers roll out; the table also gives the
time to all N durable episodes, start-up included, against the env alone's, which counts every one-time cost.
Also the wall time of ``surrol-data --help`` (target ≤ 1 s).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
RATIO_TARGET, STARTUP_TARGET_S, HELP_TARGET_S = 0.8, 3.0, 1.0


def _child_env(task: str, attempts: int, started: float) -> dict:
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401
    from surrol_data.collect.rollout import ORACLE, rollout
    from surrol_data.envs import env_id

    env = gym.make(env_id(task))
    done = []
    for seed in range(attempts):
        rollout(env, ORACLE, seed)
        done.append(time.time() - started)
    env.close()
    return {"done": done}


def _child_collect(task: str, episodes: int, out: str, workers: int, started: float) -> dict:
    from surrol_data.cli import app
    from surrol_data.datasets.writer import DatasetWriter

    done = []
    record = DatasetWriter.record

    def timed_record(self, traj, provenance):
        index = record(self, traj, provenance)
        done.append(time.time() - started)
        return index

    DatasetWriter.record = timed_record
    try:
        app(["collect", "--source", "script", "--task", task, "--num-episodes", str(episodes), "--out", out,
             "--workers", str(workers)], standalone_mode=False)
    finally:
        DatasetWriter.record = record
    from surrol_data.datasets.reader import DatasetReader

    seeds = DatasetReader(out).episodes["seed"]
    return {"done": done, "attempts": int(seeds.max()) + 1}


def _run_child(args: list[str]) -> dict:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": f"{REPO_ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    started = time.time()
    out = subprocess.run([sys.executable, __file__, "--child", json.dumps({"started": started, "args": args})],
                         capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        raise SystemExit(f"child {args[0]} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def summarize(done: list[float]) -> dict:
    """Start-up (to the first episode), median seconds per episode after it, episodes/s after start-up."""
    gaps = [b - a for a, b in zip(done, done[1:])]
    after = (len(done) - 1) / (done[-1] - done[0]) if len(done) > 1 and done[-1] > done[0] else float("nan")
    return {"startup_s": done[0], "median_s": statistics.median(gaps) if gaps else float("nan"),
            "episodes_per_s": after, "episodes": len(done), "total_s": done[-1]}


def help_seconds() -> float:
    env = {**os.environ, "PYTHONPATH": f"{REPO_ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "surrol_data.cli", "--help"], capture_output=True, env=env, check=True)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="NeedlePick")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--workers", type=int, nargs="+", default=[1])
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        spec = json.loads(args.child)
        kind, *rest = spec["args"]
        result = _child_env(*rest, spec["started"]) if kind == "env" else _child_collect(*rest, spec["started"])
        print(json.dumps(result))
        return

    from rich.console import Console
    from rich.table import Table

    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        attempts = 0
        for workers in args.workers:
            result = _run_child(["collect", args.task, args.episodes, str(Path(tmp) / f"w{workers}"), workers])
            attempts = max(attempts, result["attempts"])
            rows[f"collect --workers {workers}"] = summarize(result["done"])
        rows["env alone"] = summarize(_run_child(["env", args.task, attempts])["done"])
    env_rate = rows["env alone"]["episodes_per_s"]
    for row in rows.values():
        row["ratio"] = row["episodes_per_s"] / env_rate
        row["total_ratio"] = rows["env alone"]["total_s"] / row["total_s"]
    help_s = help_seconds()

    table = Table(title=f"{args.task}: {args.episodes} script episodes ({attempts} attempts), one run, "
                        f"{os.cpu_count()} CPUs")
    for col in ("", "episodes", "start-up s", "median s/episode", "episodes/s after start-up", "× env alone",
                "all episodes s", "× env alone, all"):
        table.add_column(col, justify="left" if not col else "right")
    for name, r in rows.items():
        table.add_row(name, str(r["episodes"]), f"{r['startup_s']:.2f}", f"{r['median_s'] * 1000:.1f} ms",
                      f"{r['episodes_per_s']:.1f}", f"{r['ratio']:.2f}", f"{r['total_s']:.1f}",
                      f"{r['total_ratio']:.2f}")
    console = Console()
    console.print(table)
    console.print(f"surrol-data --help: {help_s:.2f} s (target ≤ {HELP_TARGET_S:.0f} s); collect start-up target "
                  f"≤ {STARTUP_TARGET_S:.0f} s; ratio target ≥ {RATIO_TARGET}")
    if args.json:
        args.json.write_text(json.dumps({"task": args.task, "episodes": args.episodes, "attempts": attempts,
                                         "rows": rows, "help_s": help_s}, indent=2))


if __name__ == "__main__":
    main()

"""Env steps per second, one process, camera off and on: reset excluded and included, with oracle success.

Usage: ``uv run python benchmarks/env_throughput.py [--episodes 20] [--repeats 3] [--tasks NeedlePick ...]
[--camera off on] [--clock wall|cpu] [--json FILE] [--check]``

Each task runs ``episodes`` seeded oracle episodes per repeat; the table gives the median over repeats.
The oracle's own compute is excluded from the step timing (as in the reference measurement), the gym
wrappers (TimeLimit, order enforcing, checker) are included because users step through them.
Baseline for the ratio: the original SurRoL measured on this 2-core machine kind
(``shared/docs/reference/surrol-tasks.md`` §9.2: steps/s excluding reset; §9.3, the SurRoL-v2 branch, for the
paper's new tasks).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.table import Table

import surrol_data.envs
from surrol_data.envs import env_id

REFERENCE_STEPS_PER_S = {"NeedleReach": 59.0, "GauzeRetrieve": 115.0, "NeedlePick": 63.0, "PegTransfer": 33.0,
                         "NeedleRegrasp": 50.0, "BiPegTransfer": 16.0, "ECMReach": 418.0, "MisOrient": 783.0,
                         "StaticTrack": 30.0, "ActiveTrack": 23.0,
                         # The paper's new tasks exist only in the reference's SurRoL-v2 branch (§9.3, same
                         # machine kind, its GUI classes measured with the same harness); MatchBoardPanel is
                         # compared with v2's MatchBoardII, its drawer task.
                         "PickAndPlace": 19.8, "MatchBoard": 4.9, "MatchBoardPanel": 41.9,
                         "PegBoard": 68.5, "NeedleRings": 32.9}
TARGET_SPEED_UP = 15.0
# Issue 11: NeedlePick, the learners' task, at ≥ 1,000 steps/s with its resets counted.
TARGET_WITH_RESETS = {"NeedlePick": 1000.0}


def measure(task: str, episodes: int, camera: bool = False, clock=time.perf_counter) -> dict:
    env = gym.make(env_id(task), camera=True) if camera else gym.make(env_id(task))
    oracle = env.unwrapped.oracle_action
    step_time = reset_time = 0.0
    steps = 0
    successes = []
    for seed in range(episodes):
        t = clock()
        obs, info = env.reset(seed=seed)
        reset_time += clock() - t
        done = False
        while not done:
            action = oracle(obs)
            t = clock()
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            step_time += clock() - t
            steps += 1
        successes.append(info["is_success"])
    env.close()
    return {"excl": steps / step_time, "incl": steps / (step_time + reset_time),
            "step_ms": 1000 * step_time / steps, "reset_ms": 1000 * reset_time / episodes,
            "success": float(np.mean(successes))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(surrol_data.envs.TASKS))
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--camera", nargs="+", choices=["off", "on"], default=["off", "on"],
                        help="camera settings to measure (on = endoscope image in every observation, 128×128)")
    parser.add_argument("--camera-episodes", type=int, default=3,
                        help="episodes per repeat with the camera on (software rendering is ~100× slower)")
    parser.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                        help="wall: elapsed time; cpu: this process's CPU time (steadier on a machine shared with "
                             "other jobs, where wall time also counts the waits for a core)")
    parser.add_argument("--json", type=Path, help="also write the medians to this file ({task: {camera: {...}}})")
    parser.add_argument("--check", action="store_true",
                        help=f"exit with status 1 if a task is below {TARGET_SPEED_UP:.0f}× the reference (camera off) "
                             "or NeedlePick below 1,000 steps/s with resets")
    args = parser.parse_args()
    clock = time.perf_counter if args.clock == "wall" else time.process_time

    table = Table(title=f"env throughput (1 process, {args.clock} clock; median of {args.repeats} × {args.episodes} episodes, "
                        f"{args.camera_episodes} with the camera on; "
                        f"speed-up vs. the reference SurRoL on this machine kind, target ≥ {TARGET_SPEED_UP:.0f}× "
                        "camera off)")
    for col in ("task", "camera", "steps/s excl. reset", "steps/s incl. reset", "step ms", "reset ms",
                "oracle final success", "reference steps/s", "speed-up"):
        table.add_column(col, justify="left" if col in ("task", "camera") else "right")
    medians: dict = {}
    for task in args.tasks:
        for camera in args.camera:
            episodes = args.camera_episodes if camera == "on" else args.episodes
            runs = [measure(task, episodes, camera == "on", clock) for _ in range(args.repeats)]
            med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            medians.setdefault(task, {})[camera] = med
            ref = REFERENCE_STEPS_PER_S.get(task)
            table.add_row(task, camera, f"{med['excl']:.0f}", f"{med['incl']:.0f}", f"{med['step_ms']:.3f}",
                          f"{med['reset_ms']:.2f}", f"{med['success']:.2f}", f"{ref:.0f}" if ref else "—",
                          f"{med['excl'] / ref:.1f}×" if ref else "—")
    Console(width=170).print(table)
    if args.json:
        args.json.write_text(json.dumps(medians, indent=1))
    if args.check:
        short = shortfalls(medians)
        if short:
            raise SystemExit("below target: " + "; ".join(short))


def shortfalls(medians: dict) -> list[str]:
    """The camera-off rows that miss issue 11's speed targets, in words."""
    short = []
    for task, rows in medians.items():
        off = rows.get("off")
        if off is None:
            continue
        ref = REFERENCE_STEPS_PER_S.get(task)
        if ref and off["excl"] < TARGET_SPEED_UP * ref:
            short.append(f"{task} {off['excl']:.0f} steps/s = {off['excl'] / ref:.1f}× the reference "
                         f"(needs {TARGET_SPEED_UP * ref:.0f})")
        floor = TARGET_WITH_RESETS.get(task)
        if floor and off["incl"] < floor:
            short.append(f"{task} {off['incl']:.0f} steps/s with resets (needs {floor:.0f})")
    return short


if __name__ == "__main__":
    main()

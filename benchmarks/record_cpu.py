"""CPU per episode of `DatasetRecorder.record` against the rollout itself, in CPU seconds (``time.process_time``).

Usage: ``uv run python benchmarks/record_cpu.py [--task NeedlePick] [--episodes 40] [--slow]``

``benchmarks/collect_speed.py`` times wall clock, which only means something on an idle machine. This one rolls
``--episodes`` oracle episodes out (seeds 0..N-1) and times each rollout's CPU, then records them with the
recorder ``collect --source script`` uses (same features, provenance and checkpoints) and times each ``record``
call's CPU, so the share of collection spent writing can be read on a busy machine too: collect's episodes/s over
the env's is about ``rollout / (rollout + record)``. ``--slow`` records with lerobot's per-episode save left as it
is (``fast_save=False``, in a process where nothing patched it), for the comparison.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="NeedlePick")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--slow", action="store_true", help="lerobot's per-episode save unpatched (fast_save=False)")
    args = parser.parse_args()

    import gymnasium as gym

    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.collect.rollout import ORACLE, rollout
    from surrol_data.collect.script_source import features_for
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.envs import env_id
    from surrol_data.envs.names import dimension_names

    eid = env_id(args.task)
    env = gym.make(eid)
    trajs, rollout_s = [], []
    for seed in range(args.episodes):
        t0 = time.process_time()
        trajs.append((seed, rollout(env, ORACLE, seed)))
        rollout_s.append(time.process_time() - t0)

    record_s = []
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.process_time()
        with DatasetRecorder(Path(tmp) / "d", task=eid.split("/")[1].rsplit("-v", 1)[0], env_id=eid,
                             task_description=env.unwrapped.TASK, features=features_for(env),
                             robot_type=dimension_names(env).robot_type, fast_save=not args.slow) as rec:
            open_s = time.process_time() - t0
            for seed, traj in trajs:
                t = time.process_time()
                rec.record(traj, {"source": "script", "device": "none", "operator_id": "oracle",
                                  "skill": "scripted", "operator_simulated": False, "operator_params": "{}",
                                  "device_settings": "{}", "seed": seed, "duration_s": 0.0})
                record_s.append(time.process_time() - t)
    env.close()
    roll = statistics.mean(rollout_s)
    rec_mean = statistics.mean(record_s[1:])   # the first carries one-off checks (fast_save's) and file creation
    print(f"{args.task}, {args.episodes} episodes, {'lerobot unpatched' if args.slow else 'fast_save'}: "
          f"rollout {roll * 1000:.1f} ms CPU/episode; record {rec_mean * 1000:.1f} ms CPU/episode "
          f"(median {statistics.median(record_s[1:]) * 1000:.1f} ms, checkpoints included; "
          f"first {record_s[0] * 1000:.0f} ms); open {open_s:.2f} s CPU (lerobot's import); "
          f"rollout / (rollout + record) = {roll / (roll + rec_mean):.2f}")


if __name__ == "__main__":
    main()

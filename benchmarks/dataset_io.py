"""Dataset write and read speed: DatasetRecorder vs. plain lerobot add_frame/save_episode, and DatasetReader.

Usage: ``uv run python benchmarks/dataset_io.py [--episodes 100] [--steps 150] [--repeats 5]``

Both writers write the same state-only NeedlePick-shaped episodes (19-D state, 3-D goals, 5-D actions and
the rest of the surrol_data frame schema) with the real ``lerobot`` package, in this one process:

* ``lerobot add_frame``: ``LeRobotDataset.create`` + ``add_frame`` per frame + ``save_episode`` per episode +
  ``finalize``, nothing patched — measured first, because DatasetRecorder patches lerobot in-process.
* ``DatasetRecorder``: whole episodes handed to lerobot's ``save_episode(episode_data=...)``, provenance
  columns, a journal entry per episode (a SIGKILL loses at most the episode in progress), checkpoints
  every 10 episodes (files closed, journal emptied), card.

Then the reader on the recorder's output: every frame as numpy (``transitions()``, the issue's target
< 0.2 s for 100 x 150), every episode as a Trajectory, and one episode; medians over ``repeats``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_DISABLE_PROGRESS_BARS", "1")

import numpy as np  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from surrol_data.datasets.schema import FPS, frame_features  # noqa: E402
from surrol_data.datasets.trajectory import Trajectory  # noqa: E402

OBS_DIM, GOAL_DIM, ACT_DIM = 19, 3, 5
READ_TARGET_S = 0.2
WRITE_TARGET_FPS = 3000.0


def synthetic_episode(seed: int, steps: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    success = np.arange(steps) >= steps // 2
    return Trajectory(
        observation=rng.standard_normal((steps + 1, OBS_DIM)).astype(np.float32),
        achieved_goal=rng.standard_normal((steps + 1, GOAL_DIM)).astype(np.float32),
        desired_goal=rng.standard_normal((steps + 1, GOAL_DIM)).astype(np.float32),
        action=rng.uniform(-1, 1, (steps, ACT_DIM)).astype(np.float32),
        reward=success.astype(np.float32) - 1.0, success=success, terminated=np.zeros(steps, bool),
        tip_position=(0.01 * rng.standard_normal((steps + 1, 1, 3))).astype(np.float32),
        jaw_angle=rng.uniform(0, 1, (steps + 1, 1)).astype(np.float32),
        flags={"clutch": rng.random(steps) > 0.8, "jaw_button": rng.random(steps) > 0.5})


def write_plain_lerobot(root: Path, episodes: list[Trajectory]) -> float:
    """Seconds to write ``episodes`` frame by frame with an unpatched LeRobotDataset."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = frame_features(OBS_DIM, GOAL_DIM, ACT_DIM, 1)
    t0 = time.perf_counter()
    ds = LeRobotDataset.create("bench/plain", fps=FPS, features=features, root=root, use_videos=True,
                               video_backend="pyav")
    try:
        for traj in episodes:
            environment = np.concatenate([traj.achieved_goal, traj.desired_goal], axis=1)
            truncated = np.zeros((len(traj), 1), bool)
            truncated[-1] = not traj.terminated[-1]
            cols = {
                "observation.state": traj.observation[:-1], "observation.environment_state": environment[:-1],
                "action": traj.action,
                "next.reward": traj.reward[:, None], "next.done": traj.terminated[:, None],
                "next.truncated": truncated,
                "next.success": traj.success[:, None], "next.observation.state": traj.observation[1:],
                "next.observation.environment_state": environment[1:],
                "complementary_info.tip_position": traj.tip_position[:-1].reshape(len(traj), 3),
                "complementary_info.jaw_angle": traj.jaw_angle[:-1],
                "complementary_info.next_tip_position": traj.tip_position[1:].reshape(len(traj), 3),
                "complementary_info.next_jaw_angle": traj.jaw_angle[1:],
                "complementary_info.clutch": traj.flags["clutch"][:, None],
                "complementary_info.jaw_button": traj.flags["jaw_button"][:, None],
            }
            for t in range(len(traj)):
                ds.add_frame({**{k: v[t] for k, v in cols.items()}, "task": "bench"})
            ds.save_episode()
    finally:
        ds.finalize()
    return time.perf_counter() - t0


def write_recorder(root: Path, episodes: list[Trajectory]) -> float:
    from surrol_data.datasets.recorder import DatasetRecorder

    t0 = time.perf_counter()
    with DatasetRecorder(root, features=frame_features(OBS_DIM, GOAL_DIM, ACT_DIM, 1), task="NeedlePick",
                         env_id="SurRoL/NeedlePick-v0", task_description="bench", handle_signals=False) as rec:
        for i, traj in enumerate(episodes):
            rec.record(traj, {"source": "script", "device": "none", "skill": "scripted", "seed": i,
                              "operator_id": "oracle"})
    return time.perf_counter() - t0


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=5, help="read repeats (median reported)")
    parser.add_argument("--skip-plain", action="store_true", help="skip the plain lerobot baseline (slow)")
    args = parser.parse_args()
    console = Console()
    episodes = [synthetic_episode(i, args.steps) for i in range(args.episodes)]
    frames = args.episodes * args.steps
    work = Path(tempfile.mkdtemp(prefix="surrol_dataset_io_"))
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: F401  (import cost not timed)

        plain_s = None if args.skip_plain else write_plain_lerobot(work / "plain", episodes)
        rec_s = write_recorder(work / "recorder", episodes)

        from surrol_data.datasets.reader import DatasetReader

        root = work / "recorder"
        open_s = median_time(lambda: DatasetReader(root), args.repeats)
        reader = DatasetReader(root)
        all_s = median_time(lambda: reader.transitions(), args.repeats)
        traj_s = median_time(lambda: reader.trajectories(), args.repeats)
        one_s = median_time(lambda: reader.trajectory(args.episodes // 2), max(args.repeats, 20))
        tr = reader.transitions()
        assert len(tr["obs"]) == frames and np.array_equal(tr["obs"][: args.steps], episodes[0].observation[:-1])
    finally:
        shutil.rmtree(work, ignore_errors=True)

    table = Table(title=f"Dataset I/O, {args.episodes} episodes x {args.steps} steps = {frames} frames (state-only)")
    for col in ("what", "time", "rate", "target"):
        table.add_column(col, justify="right" if col != "what" else "left")
    if plain_s is not None:
        table.add_row("write: lerobot add_frame + save_episode", f"{plain_s:.2f} s", f"{frames / plain_s:,.0f} frames/s",
                      "baseline")
    table.add_row("write: DatasetRecorder (provenance, checkpoints)", f"{rec_s:.2f} s",
                  f"{frames / rec_s:,.0f} frames/s"
                  + (f" ({plain_s / rec_s:.1f}x)" if plain_s is not None else ""), f">= {WRITE_TARGET_FPS:,.0f}")
    table.add_row("read: open (metadata + provenance)", f"{1000 * open_s:.1f} ms", "", "")
    table.add_row("read: all frames as numpy (transitions)", f"{1000 * all_s:.1f} ms",
                  f"{frames / all_s / 1e6:.2f} M frames/s", f"< {1000 * READ_TARGET_S:.0f} ms")
    table.add_row("read: all episodes as Trajectory", f"{1000 * traj_s:.1f} ms", f"{frames / traj_s / 1e6:.2f} M frames/s",
                  "")
    table.add_row("read: one episode (trajectory)", f"{1000 * one_s:.2f} ms", "", "")
    console.print(table)


if __name__ == "__main__":
    main()

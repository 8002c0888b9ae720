"""Endoscope rendering speed: TinyRenderer vs Panda3D (offscreen), frames/s per size, and camera-on env steps/s.

Usage: ``uv run python benchmarks/render_speed.py [--task NeedlePick] [--frames 30] [--repeats 5]
[--env-steps 50]``

Frames: the same scene (``task`` after a seeded reset, the tool moved a step between frames so nothing is
cached) rendered at 128², 256² and 640×480, RGB only and RGB + depth + segmentation. Each cell is the
median over ``repeats`` runs of ``frames`` frames; the ratio column is Panda3D's frames/s over
TinyRenderer's measured in the same run. Env: oracle steps/s with ``camera=True`` at 128² for both
renderers (reset excluded), the ratio again against TinyRenderer. Panda3D renders with Mesa's llvmpipe
here (no GPU); with a GPU it is faster still.
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.table import Table
from tqdm import tqdm

import surrol_data.envs  # noqa: F401
from surrol_data.envs import env_id
from surrol_data.envs.camera import make_camera

SIZES = ((128, 128), (256, 256), (640, 480))
RENDERERS = ("tiny", "panda3d")


def frames_per_second(env, renderer: str, size, frames: int, full: bool) -> float:
    u = env.unwrapped
    cam = make_camera(u.client, size, scene_scale=u.endoscope.camera.scene_scale, renderer=renderer)
    pose = u.endoscope.ecm.eef_world
    cam.render(pose, depth=full, segmentation=full)   # first frame builds the scene: not timed
    total = 0.0
    for k in range(frames):
        env.step(np.array([0.3 if k % 2 else -0.3, 0, 0, 0, 1], np.float32))
        t = time.perf_counter()
        cam.render(pose, depth=full, segmentation=full)
        total += time.perf_counter() - t
    if hasattr(cam, "close"):
        cam.close()
    return frames / total


def env_steps_per_second(task: str, renderer: str, steps: int) -> float:
    env = gym.make(env_id(task), camera=True, camera_renderer=renderer)
    obs, _ = env.reset(seed=0)
    oracle = env.unwrapped.oracle_action
    total, done = 0.0, 0
    while done < steps:
        action = oracle(obs)
        t = time.perf_counter()
        obs, _, terminated, truncated, _ = env.step(action)
        total += time.perf_counter() - t
        done += 1
        if terminated or truncated:
            obs, _ = env.reset(seed=done)
    env.close()
    return steps / total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="NeedlePick")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--env-steps", type=int, default=50)
    args = parser.parse_args()

    console = Console()
    env = gym.make(env_id(args.task), camera=True)
    env.reset(seed=0)
    cells = [(size, full) for size in SIZES for full in (False, True)]
    results: dict[tuple, list[float]] = {}
    with tqdm(total=len(cells) * len(RENDERERS) * args.repeats, desc="frames", unit="run") as bar:
        for _ in range(args.repeats):
            for size, full in cells:
                for renderer in RENDERERS:   # interleaved: both see the same machine load
                    results.setdefault((size, full, renderer), []).append(
                        frames_per_second(env, renderer, size, args.frames, full))
                    bar.update(1)
    env.close()

    table = Table(title=f"endoscope frames/s, {args.task} (median of {args.repeats} × {args.frames} frames; "
                        "ratio = Panda3D / TinyRenderer in the same run)")
    for col in ("size", "outputs", "TinyRenderer fps", "Panda3D fps", "ratio"):
        table.add_column(col, justify="left" if col in ("size", "outputs") else "right")
    for size, full in cells:
        tiny = statistics.median(results[(size, full, "tiny")])
        panda = statistics.median(results[(size, full, "panda3d")])
        table.add_row(f"{size[0]}×{size[1]}", "RGB + depth + seg" if full else "RGB",
                      f"{tiny:.1f}", f"{panda:.1f}", f"{panda / tiny:.2f}×")
    console.print(table)

    steps: dict[str, list[float]] = {r: [] for r in RENDERERS}
    for _ in tqdm(range(args.repeats), desc="env steps", unit="run"):
        for renderer in RENDERERS:
            steps[renderer].append(env_steps_per_second(args.task, renderer, args.env_steps))
    table = Table(title=f"{args.task} env steps/s with camera=True at 128×128 (oracle actions, reset excluded; "
                        f"median of {args.repeats} × {args.env_steps} steps)")
    for col in ("camera_renderer", "steps/s", "ratio"):
        table.add_column(col, justify="left" if col == "camera_renderer" else "right")
    tiny = statistics.median(steps["tiny"])
    for renderer in RENDERERS:
        value = statistics.median(steps[renderer])
        table.add_row(renderer, f"{value:.1f}", f"{value / tiny:.2f}×")
    console.print(table)


if __name__ == "__main__":
    main()

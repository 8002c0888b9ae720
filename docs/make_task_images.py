"""Render the start of every registered task into docs/tasks/<Task>.png (the README's task table shows them).

Usage: ``uv run python docs/make_task_images.py [--tasks PickAndPlace ...] [--seed 0] [--size 320 240]``

Whatever ``surrol_data.envs.TASKS`` registers is drawn (the same list ``surrol-data tasks`` prints), so a new task
gets its picture by running this again. Each task is reset with the seed and drawn with its own ``render()``
(TinyRenderer, ``render_mode="rgb_array"``): the scene as an episode starts, before any action.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np
from PIL import Image
from rich.progress import track

import surrol_data.envs
from surrol_data.envs import env_id

OUT = Path(__file__).resolve().parent / "tasks"


def render_start(task: str, seed: int = 0, size: tuple[int, int] = (320, 240)) -> np.ndarray:
    """The (h, w, 3) uint8 picture of ``task`` right after ``reset(seed=seed)``."""
    env = gym.make(env_id(task), render_mode="rgb_array", render_size=size)
    try:
        env.reset(seed=seed)
        return np.asarray(env.render(), dtype=np.uint8)
    finally:
        env.close()


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(surrol_data.envs.TASKS),
                        help="tasks to draw (default: every registered task)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", type=int, nargs=2, default=(320, 240), metavar=("W", "H"))
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    unknown = [t for t in args.tasks if t not in surrol_data.envs.TASKS]
    if unknown:
        parser.error(f"unknown task(s) {', '.join(unknown)}; registered: {', '.join(surrol_data.envs.TASKS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    paths = []
    for task in track(args.tasks, description="rendering task starts"):
        path = args.out / f"{task}.png"
        Image.fromarray(render_start(task, args.seed, tuple(args.size))).save(path, optimize=True)
        paths.append(path)
    return paths


if __name__ == "__main__":
    for p in main():
        print(p)

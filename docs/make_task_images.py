"""Render the start of every registered task into docs/tasks/<Task>.png (the README's task table shows them).

Usage: ``uv run python docs/make_task_images.py [--tasks PickAndPlace ...] [--seed 0] [--size 640 480]
[--renderer panda3d|tiny]``

Whatever ``surrol_data.envs.TASKS`` registers is drawn (the same list ``surrol-data tasks`` prints), so a new task
gets its picture by running this again. Each task is reset with the seed and drawn as the operator sees it: the
endoscope's view (the still endoscope over a PSM scene, the task's own ECM on a camera task), by Panda3D where it
can open an offscreen buffer (TinyRenderer otherwise, or when asked): the scene as an episode starts.
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
from surrol_data.envs.camera import make_camera
from surrol_data.render.display import best_renderer
from surrol_data.render.env_view import EnvEndoscope

OUT = Path(__file__).resolve().parent / "tasks"


def render_start(task: str, seed: int = 0, size: tuple[int, int] = (640, 480), renderer: str = "tiny") -> np.ndarray:
    """The (h, w, 3) uint8 endoscope picture of ``task`` right after ``reset(seed=seed)``."""
    env = gym.make(env_id(task), render_mode="rgb_array")
    try:
        env.reset(seed=seed)
        view = EnvEndoscope(env)
        return make_camera(view.client, size, view.scene_scale, renderer).render(view.pose()).rgb
    finally:
        env.close()


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(surrol_data.envs.TASKS),
                        help="tasks to draw (default: every registered task)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    parser.add_argument("--renderer", choices=("panda3d", "tiny"), default=None,
                        help="default: panda3d where it can open an offscreen buffer, else tiny")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    unknown = [t for t in args.tasks if t not in surrol_data.envs.TASKS]
    if unknown:
        parser.error(f"unknown task(s) {', '.join(unknown)}; registered: {', '.join(surrol_data.envs.TASKS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    renderer = args.renderer or best_renderer()
    paths = []
    for task in track(args.tasks, description="rendering task starts"):
        path = args.out / f"{task}.png"
        Image.fromarray(render_start(task, args.seed, tuple(args.size), renderer)).save(path, optimize=True)
        paths.append(path)
    return paths


if __name__ == "__main__":
    for p in main():
        print(p)

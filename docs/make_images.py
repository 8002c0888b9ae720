"""Make the README's rendering pictures: the endoscope view of four tasks, TinyRenderer vs Panda3D on five, the GUI.

Usage: ``uv run python docs/make_images.py [--only endoscope renderers gui]`` (writes docs/endoscope_views.png,
docs/renderers.png, docs/gui.png, docs/gui_session.png; needs EGL/Mesa, see docs/rendering.md).

Each task is reset with seed 0 and driven by its oracle for a few steps (so tools are near their objects, jaws
open), then drawn from the task's endoscope: by Panda3D at 640×480 for the endoscope views, by both renderers from
the same pose at 320×240 for the comparison.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import surrol_data.envs  # noqa: E402,F401
from surrol_data.envs import env_id  # noqa: E402
from surrol_data.envs.camera import make_camera  # noqa: E402
from surrol_data.render.env_view import EnvEndoscope  # noqa: E402

DOCS = Path(__file__).resolve().parent
TASKS = {"NeedlePick": 18, "GauzeRetrieve": 14, "PegTransfer": 16, "NeedleRegrasp": 4, "StaticTrack": 0}
SIZE = (320, 240)
# The endoscope views: four tasks, oracle steps into each (tools over their objects, jaws open).
VIEW_TASKS = {"NeedlePick": 6, "PegTransfer": 8, "GauzeRetrieve": 6, "BiPegTransfer": 8}
VIEW_SIZE = (640, 480)


def _task_scene(task: str, steps: int):
    """The env of ``task`` after ``reset(seed=0)`` and ``steps`` oracle actions, with its endoscope."""
    env = gym.make(env_id(task), render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    for _ in range(steps):
        obs, *_ = env.step(env.unwrapped.oracle_action(obs))
    return env, EnvEndoscope(env)


def endoscope_views(path: Path) -> Path:
    """Four tasks as the surgeon sees them: Panda3D's endoscope view at 640×480, two by two."""
    fig, axes = plt.subplots(2, 2, figsize=(12.8, 9.9), dpi=100)
    for ax, (task, steps) in zip(axes.flat, VIEW_TASKS.items()):
        env, view = _task_scene(task, steps)
        ax.imshow(make_camera(view.client, VIEW_SIZE, view.scene_scale, "panda3d").render(view.pose()).rgb)
        ax.set_title(task, fontsize=12)
        ax.set_xticks([])
        ax.set_yticks([])
        env.close()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def renderer_comparison(path: Path) -> Path:
    fig, axes = plt.subplots(len(TASKS), 2, figsize=(7.2, 2.75 * len(TASKS)), dpi=110)
    for row, (task, steps) in enumerate(TASKS.items()):
        env, view = _task_scene(task, steps)
        pose = view.pose()
        for col, renderer in enumerate(("tiny", "panda3d")):
            image = make_camera(view.client, SIZE, view.scene_scale, renderer).render(pose).rgb
            ax = axes[row, col]
            ax.imshow(image)
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title("TinyRenderer (camera_renderer='tiny')" if col == 0
                             else "Panda3D (camera_renderer='panda3d')", fontsize=9)
            if col == 0:
                ax.set_ylabel(task, fontsize=10)
        env.close()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def gui_pictures(idle_path: Path, session_path: Path) -> None:
    from surrol_data.gui.app import TrainingApp

    app = TrainingApp(out=tempfile.mkdtemp(prefix="surrol_gui_docs_"), offscreen=True)
    app.set_session("operator", "expert", "docs")
    app.choose_task("NeedlePick")
    app.frame()
    app.screenshot(idle_path)

    def photographer(task):
        # Mid-task, jaw closed on the needle: the moment worth a picture; then end the session.
        if app.hud.steps == 75 and not session_path.exists():
            app.screenshot(session_path)
            app.request_exit()
        return task.cont

    app.base.taskMgr.add(photographer, "photographer")
    app.play()
    app.run()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=("endoscope", "renderers", "gui"),
                        default=["endoscope", "renderers", "gui"], help="which pictures to make (default: all)")
    only = parser.parse_args(argv).only
    if "endoscope" in only:
        print(endoscope_views(DOCS / "endoscope_views.png"))
    if "renderers" in only:
        print(renderer_comparison(DOCS / "renderers.png"))
    if "gui" in only:
        session = DOCS / "gui_session.png"
        session.unlink(missing_ok=True)
        gui_pictures(DOCS / "gui.png", session)
        print(DOCS / "gui.png", session)


if __name__ == "__main__":
    main()

"""Make the README's rendering pictures: TinyRenderer vs Panda3D on five tasks, and the training GUI.

Usage: ``uv run python docs/make_images.py`` (writes docs/renderers.png, docs/gui.png, docs/gui_session.png;
needs EGL/Mesa, see README "Rendering and GUI").

Each task is reset with seed 0 and driven by its oracle for a few steps (so tools are near their objects);
both renderers then draw the same PyBullet scene from the same endoscope pose at 320×240.
"""

from __future__ import annotations

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


def renderer_comparison(path: Path) -> Path:
    fig, axes = plt.subplots(len(TASKS), 2, figsize=(7.2, 2.75 * len(TASKS)), dpi=110)
    for row, (task, steps) in enumerate(TASKS.items()):
        env = gym.make(env_id(task), render_mode="rgb_array")
        obs, _ = env.reset(seed=0)
        for _ in range(steps):
            obs, *_ = env.step(env.unwrapped.oracle_action(obs))
        view = EnvEndoscope(env)
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


def main() -> None:
    print(renderer_comparison(DOCS / "renderers.png"))
    session = DOCS / "gui_session.png"
    session.unlink(missing_ok=True)
    gui_pictures(DOCS / "gui.png", session)
    print(DOCS / "gui.png", session)


if __name__ == "__main__":
    main()

"""The training GUI driven end to end: open, choose NeedlePick, play with the simulated operator, save an
episode, exit; the dataset validates. Offscreen in-process, and on a real X display under Xvfb through the CLI.

Skipped (naming the Debian packages) where Panda3D cannot render: EGL/Mesa for offscreen, xvfb for the window.
"""

import os
import shutil
import subprocess
import sys
import time

import pytest

from surrol_data.render.display import unavailable_reason

pytestmark = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))

SAVE_AT_STEP = 12   # the scripted trainee saves attempt 1 here, mid-task (so it is saved, not a success)


def test_gui_play_save_exit_records_a_valid_dataset(tmp_path):
    from surrol_data.collect.haptic_source import SKILLS
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.validate import validate_dataset
    from surrol_data.gui.app import DEVICES, TrainingApp

    app = TrainingApp(out=tmp_path, offscreen=True, size=(640, 360))
    clicks = []

    def trainee(task):
        """Clicks as a person would, watching the HUD: save attempt 1 mid-way, exit during attempt 2."""
        hud = app.hud
        if hud.attempt == 1 and hud.steps == SAVE_AT_STEP and "save" not in clicks:
            clicks.append("save")
            app.buttons["save"].commandFunc(None)
        elif hud.attempt == 2 and hud.steps == 3 and "exit" not in clicks:
            clicks.append("exit")
            app.buttons["exit"].commandFunc(None)
        return task.cont

    app.base.taskMgr.add(trainee, "scripted-trainee")
    app.cards["NeedlePick"].commandFunc(None)           # a click on the task's card
    app.device_menu.set(DEVICES.index("operator"))      # as choosing in the menus does
    app.skill_menu.set(SKILLS.index("expert"))
    app.operator_entry.enterText("trainee-7")
    app._typing(False)                                  # the field loses the focus: its text is taken
    assert app.task == "NeedlePick" and app.device == "operator" and app.skill == "expert"
    app.buttons["play"].commandFunc(None)
    app.run()

    assert clicks == ["save", "exit"]
    root = tmp_path / "NeedlePick"
    assert validate_dataset(root) == []
    reader = DatasetReader(root)
    episodes = reader.episodes
    assert len(episodes) == 1
    row = episodes.iloc[0]
    assert row["source"] == "haptic" and row["device"] == "simulated-operator"
    assert row["skill"] == "expert" and row["operator_id"] == "trainee-7"
    # Saved as it stood: the steps before the click, no more.
    assert len(reader.trajectory(int(row["episode_index"])).action) == SAVE_AT_STEP


def test_keyboard_keys_of_the_window_drive_the_tool(tmp_path):
    from surrol_data.gui.app import TrainingApp
    from surrol_data.gui.keys import WindowKeys

    app = TrainingApp(out=tmp_path, offscreen=True, size=(480, 270))
    app.choose_task("NeedleReach")
    app.set_session("keyboard", "novice", "k1")
    send = app.base.messenger.send

    def hand(task):
        # The events a real key press makes in the window: hold `d` (tool +x) for a while, then Esc.
        if app.hud.steps == 1 and app.hud.attempt == 1:
            send(WindowKeys.DOWN_EVENT, ["d"])
        elif app.hud.steps == 8:
            send(WindowKeys.UP_EVENT, ["d"])
            send(WindowKeys.DOWN_EVENT, ["escape"])
        return task.cont

    # Panda3D's task manager is one per process: a "hand" task left by an earlier test in this process
    # would press its own keys in this window
    app.base.taskMgr.remove("hand")
    app.base.taskMgr.add(hand, "hand")
    app.exit_after_session = True   # Esc ends the session; the window would stay open for the next one
    app.play()
    app.run()
    assert app.last_error is None and app.last_result.ended_by == "operator"
    assert app.hud.path_m > 0.002   # the held key moved the tool millimetres (untouched, it stays still)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (Debian package `xvfb`) for an X display")
def test_gui_on_an_x_display_through_the_cli(tmp_path):
    display = ":97"
    xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        env = {**os.environ, "DISPLAY": display}
        shot = tmp_path / "window.png"
        run = subprocess.run([sys.executable, "-m", "surrol_data.cli", "gui", "--task", "NeedleReach",
                              "--device", "operator", "--skill", "expert", "--autoplay", "1", "--onscreen",
                              "--out", str(tmp_path / "out"), "--screenshot", str(shot)],
                             env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stdout + run.stderr
        assert "recorded 1 episodes" in run.stdout
        assert shot.stat().st_size > 10_000
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=10)
    from surrol_data.datasets.validate import validate_dataset

    assert validate_dataset(tmp_path / "out" / "NeedleReach") == []


def test_hud_counts_time_path_and_flags_per_attempt():
    from surrol_data.envs.units import CONTROL_PERIOD_S
    from surrol_data.gui.hud import Hud

    hud = Hud(task="NeedlePick")
    tips = [(0.0, 0.0, 0.0), (0.03, 0.0, 0.0), (0.03, 0.04, 0.0)]
    for step, tip in enumerate(tips, start=1):
        hud.update(step, {"tip_position": [tip], "is_success": step == 3}, {"jaw_button": step >= 2, "clutch": False})
    assert hud.attempt == 1 and hud.steps == 3
    assert hud.path_m == pytest.approx(0.07)
    assert hud.time_s == pytest.approx(3 * CONTROL_PERIOD_S)
    assert hud.success and hud.jaw_closed and not hud.clutch
    hud.update(1, {"tip_position": [(1.0, 1.0, 1.0)], "is_success": False}, {})   # a new attempt starts afresh
    assert hud.attempt == 2 and hud.path_m == 0.0 and not hud.success


@pytest.mark.parametrize("args, message", [
    (["--task", "NeedleJuggle"], "unknown task"),
    (["--device", "joystick"], "--device must be one of"),
    (["--skill", "wizard"], "--skill must be one of"),
    (["--autoplay", "1"], "--autoplay needs --task"),
])
def test_gui_cli_refuses_bad_options(args, message):
    from typer.testing import CliRunner

    from surrol_data.cli import app

    result = CliRunner().invoke(app, ["gui", *args])
    assert result.exit_code == 2
    assert message in " ".join(result.output.split())

"""`surrol-data gui` where no window can be seen ends at once with one error that says how to get one (a desktop,
Xvfb, --onscreen) or how to run headless (--offscreen --autoplay), instead of drawing an invisible window forever."""

import os
import subprocess
import sys

import pytest
from typer.testing import CliRunner

pytest.importorskip("panda3d", reason="the GUI needs Panda3D (the render extra)")


def _gui(args: list[str], **env_changes) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(env_changes)
    # a GUI that waits for nobody would run until the timeout: TimeoutExpired fails the test
    return subprocess.run([sys.executable, "-m", "surrol_data.cli", "gui", *args], env=env, capture_output=True,
                          text=True, timeout=120)


def test_the_gui_without_a_display_names_xvfb_and_onscreen_and_exits():
    run = _gui([])
    said = " ".join((run.stdout + run.stderr).split())
    assert run.returncode == 2, said
    assert "no display" in said and "xvfb-run" in said and "--onscreen" in said and "--offscreen" in said
    assert "Traceback" not in said


def test_an_offscreen_gui_that_does_not_play_by_itself_is_refused():
    from surrol_data.cli import app

    run = CliRunner().invoke(app, ["gui", "--offscreen"])
    said = " ".join(run.output.split())
    assert run.exit_code == 2
    assert "--autoplay" in said and "--onscreen" in said


def test_a_display_that_cannot_be_opened_is_one_error_not_a_traceback(tmp_path):
    run = _gui(["--task", "NeedleReach", "--device", "operator", "--skill", "expert", "--autoplay", "1",
                "--out", str(tmp_path)], DISPLAY=":87")   # no X server listens there
    said = " ".join((run.stdout + run.stderr).split())
    assert run.returncode == 2, said
    assert "could not open a window on the display ':87'" in said and "xvfb-run" in said
    assert "Traceback" not in said and not any(tmp_path.iterdir())

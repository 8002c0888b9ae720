"""``render_mode="human"`` without an X display is a Python exception that says what to do; PyBullet alone would
end the whole process (a notebook kernel, a test run) with "cannot connect to X server"."""

import os
import subprocess
import sys

import pytest

PROBE = """
import gymnasium as gym
import surrol_data.envs
from surrol_data.envs.physics import NoDisplayError
try:
    env = gym.make("SurRoL/NeedleReach-v0", render_mode="human")
    env.reset(seed=0)
except NoDisplayError as e:
    print("CAUGHT", e)
"""


@pytest.mark.parametrize("display", [None, ":12345"])   # unset, and set to a display no X server answers
def test_human_render_mode_without_a_display_raises_a_clear_error(display):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    if display is not None:
        env["DISPLAY"] = display
    run = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr   # the process lives on
    assert "CAUGHT render_mode='human' opens a PyBullet window, which needs an X display" in run.stdout
    assert "xvfb" in run.stdout and "rgb_array" in run.stdout
    assert ("DISPLAY is unset" if display is None else "no X server answers at DISPLAY=':12345'") in run.stdout

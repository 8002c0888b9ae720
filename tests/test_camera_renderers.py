"""Renderers plug into the envs by name, without the envs importing them (docs/architecture.md).

``camera_renderer="tiny"`` is built into :mod:`surrol_data.envs.camera`; ``"panda3d"`` comes from the
``surrol_data.renderers`` entry point that pyproject.toml declares, loaded the first time the name is asked for;
anything else can be registered. These checks need no OpenGL (tests/test_render_panda3d.py renders).
"""

import json
import subprocess
import sys

import pytest

from surrol_data import extras
from surrol_data.envs import camera


def test_the_installed_renderers_are_tiny_and_panda3d():
    names = camera.camera_renderers()
    assert names[0] == "tiny" and "panda3d" in names, (
        f"{names}: the panda3d entry point is not installed; refresh the package metadata "
        "(`uv pip install -e . --no-deps`)")


def test_an_unknown_renderer_is_refused_with_the_names_there_are():
    with pytest.raises(ValueError, match="camera_renderer must be one of tiny, panda3d, got 'ogre'"):
        camera.make_camera(None, renderer="ogre")


def test_a_registered_renderer_is_built_by_name(monkeypatch):
    made = []

    def factory(client, size, scene_scale=1.0):
        made.append((client, size, scene_scale))
        return "a camera"

    monkeypatch.setitem(camera._RENDERERS, "fake", factory)
    assert "fake" in camera.camera_renderers()
    assert camera.make_camera("client", (32, 24), scene_scale=2.0, renderer="fake") == "a camera"
    assert made == [("client", (32, 24), 2.0)]


def test_panda3d_without_panda3d_names_the_render_extra(monkeypatch):
    monkeypatch.delitem(camera._RENDERERS, "panda3d", raising=False)   # found afresh through the entry point
    monkeypatch.setitem(sys.modules, "panda3d", None)                  # as if it were not installed
    with pytest.raises(extras.MissingExtra, match=r"surrol-data\[render\]"):
        camera.make_camera(None, (64, 64), renderer="panda3d")


def test_envs_with_a_camera_do_not_import_the_renderers():
    code = ("import json, sys, gymnasium as gym\n"
            "import surrol_data.envs\n"
            "env = gym.make('SurRoL/NeedleReach-v0', camera=True, camera_size=(32, 32))\n"
            "env.reset(seed=0)\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('surrol_data.render') or "
            "m.startswith('panda3d'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []

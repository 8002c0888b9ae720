"""docs/make_task_images.py draws every registered task's start (the README's task table shows the pictures)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import surrol_data.envs

SCRIPT = Path(__file__).resolve().parents[1] / "docs" / "make_task_images.py"


def _script():
    spec = importlib.util.spec_from_file_location("make_task_images", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_draws_the_registered_tasks_it_is_asked_for(tmp_path):
    script = _script()
    paths = script.main(["--tasks", "MatchBoard", "ECMReach", "--size", "96", "72", "--out", str(tmp_path)])
    assert [p.name for p in paths] == ["MatchBoard.png", "ECMReach.png"]
    for p in paths:
        image = np.asarray(Image.open(p))
        assert image.shape == (72, 96, 3)
        assert image.reshape(-1, 3).std(axis=0).max() > 10     # a scene, not a blank frame
    with pytest.raises(SystemExit):
        script.main(["--tasks", "NoSuchTask", "--out", str(tmp_path)])


def test_every_registered_task_has_its_picture_in_docs():
    missing = [t for t in surrol_data.envs.TASKS if not (SCRIPT.parent / "tasks" / f"{t}.png").exists()]
    assert not missing, f"run `uv run python docs/make_task_images.py` to draw {missing}"
    # The endoscope's view as the GUI's thumbnails and the README show it: 640×480 (issue 29).
    sizes = {t: Image.open(SCRIPT.parent / "tasks" / f"{t}.png").size for t in surrol_data.envs.TASKS}
    wrong = {t: size for t, size in sizes.items() if size != (640, 480)}
    assert not wrong, f"task pictures not 640×480: {wrong}; remake them with `uv run python docs/make_task_images.py`"

"""``collect --camera --renderer tiny|panda3d``: the chosen renderer draws every collecting env's endoscope (one
process, ``--workers``, ``--shards``, haptic and intervention sessions) and the dataset records it; appending or
merging across renderers is refused like across camera versions.

Real PyBullet, lerobot and Panda3D offscreen; the Panda3D tests are skipped (with the Debian packages to install)
where Panda3D cannot open an offscreen OpenGL buffer.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from typer.testing import CliRunner

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.cli import app
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.schema import SIDECAR_PATH
from surrol_data.envs import env_id
from surrol_data.render.display import unavailable_reason

needs_gl = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))

TASK = "NeedleReach"
W, H = 40, 32
STEPS = 6
# Mean absolute difference (0..255) of a decoded first frame from the image its env draws at reset: AV1 at this
# size loses a few levels; the other renderer's image of the same scene is far further (measured at seed 0: 3.6 vs 44).
DECODED_TOLERANCE = 8.0


def _run(args: list[str]):
    return CliRunner().invoke(app, args)


def _ok(args: list[str]) -> str:
    run = _run(args)
    assert run.exit_code == 0, f"{args}: {run.output}"
    return " ".join(run.output.split())


def _collect(out: Path, *extra: str, episodes: int = 2, source: str = "script") -> Path:
    device = ["--device", "operator", "--skill", "expert", "--operator-id", "e1"] if source != "script" else []
    _ok(["collect", "--source", source, *device, "--task", TASK, "--num-episodes", str(episodes), "--seed", "0",
         "--max-steps", str(STEPS), "--keep-failures", "--camera", "--camera-size", f"{W}x{H}", *extra,
         "--out", str(out)])
    return out


def _renderer(root: Path) -> str:
    return json.loads((root / SIDECAR_PATH).read_text())["camera_renderer"]


def _first_frame(root: Path, ep: int = 0) -> np.ndarray:
    return DatasetReader(root).frames(ep)["endoscope"][0].astype(np.float64)


def _direct(renderer: str, seed: int = 0) -> np.ndarray:
    """The endoscope image an env drawn by ``renderer`` shows at ``reset(seed)``."""
    env = gym.make(env_id(TASK), camera=True, camera_size=(W, H), camera_renderer=renderer)
    try:
        return env.reset(seed=seed)[0]["image"].astype(np.float64)
    finally:
        env.close()


@pytest.fixture(scope="module")
def collected(tmp_path_factory):
    root = tmp_path_factory.mktemp("renderer")
    return {"panda3d": _collect(root / "panda3d", "--renderer", "panda3d"),
            "tiny": _collect(root / "tiny", "--renderer", "tiny")}


@needs_gl
def test_panda3d_dataset_is_valid_records_its_renderer_and_holds_panda3d_frames(collected):
    panda, tiny = collected["panda3d"], collected["tiny"]
    assert "is a valid surrol_data dataset" in _ok(["validate", str(panda)])
    assert _renderer(panda) == "panda3d" and _renderer(tiny) == "tiny"
    assert re.search(r"camera renderer\W+panda3d", _ok(["info", str(panda)]))   # a row of the info table
    direct = {r: _direct(r) for r in ("panda3d", "tiny")}
    assert np.abs(direct["panda3d"] - direct["tiny"]).mean() > 4 * DECODED_TOLERANCE   # the renderers differ
    for name, root in collected.items():
        other = "tiny" if name == "panda3d" else "panda3d"
        frame = _first_frame(root)
        assert np.abs(frame - direct[name]).mean() < DECODED_TOLERANCE, f"{name}: not the {name} env's image"
        assert np.abs(frame - direct[other]).mean() > 2 * DECODED_TOLERANCE, f"{name}: drawn by {other}"


@needs_gl
def test_append_or_merge_across_renderers_is_refused(collected, tmp_path):
    panda = collected["panda3d"]
    for extra in (["--renderer", "tiny"], []):      # without --renderer the camera is TinyRenderer's
        run = _run(["collect", "--source", "script", "--task", TASK, "--num-episodes", "1", "--max-steps",
                    str(STEPS), "--keep-failures", "--camera", "--camera-size", f"{W}x{H}", *extra, "--append",
                    "--out", str(panda)])
        said = " ".join(run.output.split())
        assert run.exit_code == 2 and "Traceback" not in run.output, run.output
        assert "'panda3d' renderer" in said and "--renderer panda3d" in said, said
    assert len(DatasetReader(panda)) == 2 and _renderer(panda) == "panda3d"   # nothing was added
    run = _run(["merge", str(panda), str(collected["tiny"]), "--out", str(tmp_path / "mixed")])
    assert run.exit_code == 2 and "renderer" in run.output and "Traceback" not in run.output, run.output
    assert not (tmp_path / "mixed").exists()


def _drawn_as_in_one_process(out: Path, collected: dict) -> None:
    assert _renderer(out) == "panda3d"
    single = collected["panda3d"]
    for ep in range(2):
        seed = int(DatasetReader(out).episodes["seed"].iloc[ep])
        assert seed == int(DatasetReader(single).episodes["seed"].iloc[ep])
        assert np.abs(_first_frame(out, ep) - _first_frame(single, ep)).mean() < 1.0, f"episode {ep} (seed {seed})"


@needs_gl
# --shards is slow here (two fresh shard processes, each importing lerobot and Panda3D: ~25 s of CPU); the test after
# this one checks the same in one process, and test_collect_workers' [shards] case the shard processes.
@pytest.mark.parametrize("parallel", [["--workers", "2"], pytest.param(["--shards", "2"], marks=pytest.mark.slow)],
                         ids=["workers", "shards"])
def test_parallel_collection_draws_with_the_chosen_renderer(collected, tmp_path, parallel):
    _drawn_as_in_one_process(_collect(tmp_path / "parallel", "--renderer", "panda3d", *parallel), collected)


@needs_gl
def test_every_shard_draws_with_the_chosen_renderer(collected, tmp_path, monkeypatch):
    """`collect --shards 2 --renderer panda3d` with each shard recorded by the function a shard process runs, here
    rather than in a process pool: the renderer reaches every shard and the merged dataset."""
    from surrol_data.collect import shards

    def here(items, progress, say):
        for item in items:
            shards.record_shard(*item)

    monkeypatch.setattr(shards, "_locally", here)
    _drawn_as_in_one_process(_collect(tmp_path / "shards", "--renderer", "panda3d", "--shards", "2"), collected)


@needs_gl
@pytest.mark.parametrize("source", ["haptic", "intervene"])
def test_operator_collection_records_the_renderer(tmp_path, source):
    policy = ["--policy", "oracle"] if source == "intervene" else []
    out = _collect(tmp_path / source, "--renderer", "panda3d", *policy, source=source, episodes=1)
    assert _renderer(out) == "panda3d"
    assert np.abs(_first_frame(out) - _direct("panda3d")).mean() < DECODED_TOLERANCE


def test_renderer_needs_the_camera_and_a_known_name(tmp_path):
    base = ["collect", "--source", "script", "--task", TASK, "--num-episodes", "1", "--out", str(tmp_path / "x")]
    run = _run([*base, "--renderer", "panda3d"])
    assert run.exit_code == 2 and "--camera" in run.output and "Traceback" not in run.output, run.output
    run = _run([*base, "--camera", "--renderer", "vulkan"])
    said = " ".join(run.output.split())
    assert run.exit_code == 2 and "tiny, panda3d" in said and "'vulkan'" in said, said
    assert not (tmp_path / "x").exists()


def test_panda3d_that_cannot_draw_here_is_said_up_front_in_the_commands_words(tmp_path):
    """Where Panda3D finds no EGL (glvnd pointed at no vendor library: what a machine without Mesa's EGL is like), `collect
    --renderer panda3d` stops before any dataset exists, names the packages and the option that does without."""
    out = tmp_path / "x"
    run = subprocess.run([sys.executable, "-m", "surrol_data.cli", "collect", "--source", "script", "--task", TASK,
                          "--num-episodes", "1", "--camera", "--renderer", "panda3d", "--out", str(out)],
                         capture_output=True, text=True, timeout=300,
                         env={**os.environ, "__EGL_VENDOR_LIBRARY_FILENAMES": str(tmp_path / "no_vendor.json")})
    said = " ".join((run.stdout + run.stderr).split())
    assert run.returncode == 2 and "Traceback" not in said, said[-3000:]
    assert "libegl-mesa0" in said and "--renderer tiny" in said and "camera_renderer" not in said, said
    assert not out.exists()

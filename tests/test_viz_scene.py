"""Rerun shows the task's scene as meshes that move: one Mesh3D per link, logged once, and a Transform3D per step,
read back from a real .rrd written from a real (replayed) episode."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

rr = pytest.importorskip("rerun")
from rerun.experimental import RrdReader  # noqa: E402

import surrol_data.envs  # noqa: E402,F401
from surrol_data.collect.rollout import rollout  # noqa: E402
from surrol_data.envs import env_id  # noqa: E402
from surrol_data.viz.rerun_log import save_rrd  # noqa: E402

STEPS = 6


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    env = gym.make(env_id("NeedlePick"))
    traj = rollout(env, "oracle", seed=3, max_steps=STEPS)
    env.close()
    path = save_rrd(tmp_path_factory.mktemp("rrd") / "scene.rrd",
                    [("oracle", traj, {"source": "script", "env_id": env_id("NeedlePick"), "seed": 3})], scene=True)
    chunks = list(RrdReader(Path(path)).stream())
    return traj, chunks


def _scene(chunks, static: bool) -> dict[str, list]:
    out: dict[str, list] = {}
    for ch in chunks:
        if ch.entity_path.startswith("/world/oracle/scene/") and ch.is_static == static:
            out.setdefault(ch.entity_path, []).append(ch.to_record_batch())
    return out


def test_every_link_is_a_mesh_logged_once(recorded):
    _, chunks = recorded
    meshes = {path: rbs for path, rbs in _scene(chunks, static=True).items()
              if any("Mesh3D:vertex_positions" in rb.schema.names for rb in rbs)}
    links = {path.rsplit("/", 1)[1] for path in meshes}
    # The instrument's shaft (3), wrist (4) and both blades (6, 7), and the scene's bodies (the base links).
    assert {"link3", "link4", "link6", "link7", "link-1"} <= links, sorted(links)
    assert len({path.rsplit("/", 2)[1] for path in meshes}) >= 5, "pad/tray, table, needle, PSM, goal: bodies"
    for rbs in meshes.values():
        positions = [p for rb in rbs for row in rb.column("Mesh3D:vertex_positions").to_pylist() for p in row]
        assert len(positions) >= 24   # a solid, not a point


def test_every_link_moves_by_a_transform_per_step(recorded):
    traj, chunks = recorded
    moving = _scene(chunks, static=False)
    assert moving, "no per-step transforms"
    for path, rbs in moving.items():
        rows = sum(rb.num_rows for rb in rbs)
        assert rows == len(traj) + 1, (path, rows)
        assert any("Transform3D:translation" in rb.schema.names for rb in rbs)
    blade = next(rbs for path, rbs in moving.items() if path.endswith("/link6"))
    translations = np.array([t for rb in blade for t in rb.column("Transform3D:translation").to_pylist()]).reshape(-1, 3)
    # The blade follows the recorded tool tip (within the 10 mm blade), real metres.
    tips = np.asarray(traj.tip_position, np.float64)[:, 0]
    assert np.abs(translations - tips).max() < 0.015
    assert np.linalg.norm(translations[-1] - translations[0]) > 0.005, "the oracle moved the tool"


def test_the_replay_follows_the_recording(recorded):
    _, chunks = recorded
    warnings = [ch for ch in chunks if ch.entity_path == "/world/oracle/scene" and ch.is_static]
    assert not warnings, "the replayed tool tip drifted from the recorded one"


def test_a_scene_needs_the_env_and_seed(tmp_path):
    from test_viz import synthetic_needle_pick

    with pytest.raises(ValueError, match="provenance needs env_id and seed"):
        save_rrd(tmp_path / "x.rrd", [("a", synthetic_needle_pick(4, seed=0), {"source": "script"})], scene=True)
    assert not (tmp_path / "x.rrd").exists(), "bad input leaves no half-written recording"

"""Rerun logging: the .rrd is written headlessly, verifies with the CLI and reads back with the right content."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
from rerun.experimental import RrdReader  # noqa: E402

from surrol_data.datasets.trajectory import Trajectory  # noqa: E402
from surrol_data.viz.rerun_log import entity_label, log_trajectories, save_rrd  # noqa: E402

TABLE_Z = 0.675


def synthetic_needle_pick(steps: int, seed: int, with_image: bool = False) -> Trajectory:
    """A straight-line reach to an object, grasp, lift to the goal; success on the last three steps."""
    rng = np.random.default_rng(seed)
    start = np.array([0.0, 0.0, TABLE_Z + 0.05])
    obj = np.array([0.02, -0.01, TABLE_Z + 0.002]) + rng.normal(0, 0.002, 3)
    goal = obj + np.array([0.0, 0.0, 0.04])
    half = steps // 2
    tip = np.concatenate([np.linspace(start, obj, half + 1), np.linspace(obj, goal, steps - half + 1)[1:]])
    obj_path = np.where(np.arange(steps + 1)[:, None] > half, tip, obj)
    observation = np.zeros((steps + 1, 19), np.float32)
    observation[:, 0:3] = tip
    observation[:, 7:10] = obj_path
    jaw_cmd = np.where(np.arange(steps) >= half, -1.0, 1.0)
    action = np.zeros((steps, 5), np.float32)
    action[:, :3] = np.clip(np.diff(tip, axis=0) / 0.01, -1, 1)
    action[:, 3] = rng.uniform(-0.1, 0.1, steps)
    action[:, 4] = jaw_cmd
    success = np.zeros(steps, bool)
    success[-3:] = True
    images = {"front": rng.integers(0, 255, (steps + 1, 12, 16, 3), dtype=np.uint8)} if with_image else {}
    return Trajectory(
        observation=observation,
        achieved_goal=obj_path.astype(np.float32),
        desired_goal=np.repeat(goal[None].astype(np.float32), steps + 1, axis=0),
        action=action,
        reward=np.where(success, 0.0, -1.0).astype(np.float32),
        success=success,
        terminated=np.zeros(steps, bool),
        tip_position=tip[:, None, :].astype(np.float32),
        jaw_angle=np.concatenate([[0.7], np.where(jaw_cmd < 0, 0.0, 0.7)])[:, None].astype(np.float32),
        flags={"clutch": np.arange(steps) == 2, "jaw_button": jaw_cmd < 0},
        images=images,
    )


def _chunks(path: Path) -> list:
    return list(RrdReader(path).stream())


def _rerun_cli() -> str:
    candidate = Path(sys.executable).parent / "rerun"
    return str(candidate) if candidate.exists() else (shutil.which("rerun") or "")


@pytest.fixture(scope="module")
def items():
    return [
        ("oracle", synthetic_needle_pick(12, seed=0, with_image=True),
         {"source": "script", "device": "none", "skill": "scripted", "seed": 0,
          "device_settings": {"scale": [1.0, 1.0, 1.0], "jaw_ramp": 0.2}}),
        ("haptic op07", synthetic_needle_pick(16, seed=1),
         {"source": "haptic", "device": "touch", "operator_id": "op07", "skill": "novice", "seed": 1,
          "simulated_params": None}),
    ]


@pytest.fixture(scope="module")
def rrd(tmp_path_factory, items) -> Path:
    return save_rrd(tmp_path_factory.mktemp("viz") / "episodes.rrd", items, recording_name="test episodes")


def test_rrd_is_written(rrd):
    assert rrd.exists() and rrd.stat().st_size > 1000


def test_rrd_verifies_with_cli(rrd):
    cli = _rerun_cli()
    if not cli:
        pytest.skip("rerun CLI not found")
    env = {**os.environ, "RERUN_ANALYTICS": "off"}
    out = subprocess.run([cli, "rrd", "verify", str(rrd)], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "without error" in out.stdout + out.stderr


def test_entities_for_both_labels(rrd, items):
    paths = {ch.entity_path for ch in _chunks(rrd)}
    for label, traj, _ in items:
        name = entity_label(label)
        expected = {f"/world/{name}/arm0/path", f"/world/{name}/arm0/trail", f"/world/{name}/arm0/tip",
                    f"/world/{name}/object", f"/world/{name}/goal", f"/plots/{name}/action",
                    f"/plots/{name}/jaw_angle", f"/plots/{name}/flags", f"/plots/{name}/reward",
                    f"/plots/{name}/success", f"/provenance/{name}"}
        expected |= {f"/camera/{name}/{cam}" for cam in traj.images}
        assert expected <= paths, sorted(expected - paths)
    assert "/world/haptic_op07/arm0/tip" in paths   # the space in the label became '_'


def test_actions_round_trip(rrd, items):
    for label, traj, _ in items:
        rows = [ch.to_record_batch() for ch in _chunks(rrd)
                if ch.entity_path == f"/plots/{entity_label(label)}/action" and not ch.is_static]
        steps = np.concatenate([rb.column("step").to_numpy() for rb in rows])
        values = np.concatenate([np.array(rb.column("Scalars:scalars").to_pylist()) for rb in rows])
        order = np.argsort(steps)
        np.testing.assert_array_equal(steps[order], np.arange(len(traj)))
        np.testing.assert_array_equal(values[order], np.asarray(traj.action, np.float64))


def test_time_timeline_and_growing_trail(rrd, items):
    label, traj, _ = items[0]
    rb = next(ch.to_record_batch() for ch in _chunks(rrd)
              if ch.entity_path == f"/world/{label}/arm0/trail" and not ch.is_static)
    assert "time" in rb.schema.names
    strips = rb.column("LineStrips3D:strips").to_pylist()
    lengths = [len(s[0]) for s in strips]
    assert lengths == list(range(1, len(traj) + 2))   # one more point per step


def test_provenance_and_outcome_property(rrd):
    props = {}
    for ch in _chunks(rrd):
        if ch.entity_path.startswith("/__properties/"):
            props[ch.entity_path] = ch.to_record_batch().to_pylist()[0]
    oracle = props["/__properties/oracle"]
    assert oracle["source"] == ["script"]
    assert oracle["device_settings.scale"] == [1.0, 1.0, 1.0]
    assert oracle["outcome.success"] == [True]
    assert oracle["outcome.steps_to_success"] == [10]
    haptic = next(v for k, v in props.items() if "haptic" in k)
    assert haptic["operator_id"] == ["op07"]
    assert "simulated_params" not in haptic   # None values are dropped, not stored untyped


def test_blueprint_is_stored(rrd):
    assert RrdReader(rrd).blueprints(), "no blueprint store in the .rrd"


def test_rejects_bad_input(tmp_path, items):
    with pytest.raises(ValueError, match="unique"):
        save_rrd(tmp_path / "dup.rrd", [items[0], ("oracle", items[1][1], {})])
    with pytest.raises(ValueError, match=".rrd"):
        save_rrd(tmp_path / "x.bin", items)
    with pytest.raises(ValueError, match="no episodes"):
        log_trajectories(tmp_path / "empty.rrd", [])
    assert not list(tmp_path.glob("*.rrd"))   # validation happens before the file is opened


def test_log_into_caller_stream_with_jpeg(tmp_path, items):
    rec = rr.RecordingStream("surrol_data_test", recording_id="caller")
    path = tmp_path / "caller.rrd"
    rec.save(path)
    assert log_trajectories(rec, items[:1], jpeg_quality=80, trail_length=4) is rec
    rec.flush()
    rec.disconnect()
    chunks = _chunks(path)
    image = [ch for ch in chunks if ch.entity_path == "/camera/oracle/front" and not ch.is_static]
    assert image and "EncodedImage:blob" in image[0].to_record_batch().schema.names
    trail = next(ch.to_record_batch() for ch in chunks
                 if ch.entity_path == "/world/oracle/arm0/trail" and not ch.is_static)
    assert max(len(s[0]) for s in trail.column("LineStrips3D:strips").to_pylist()) == 4


# ------------------------------------------------------------------ instruments drawn from recorded states
def test_instrument_matches_the_simulated_arm_and_opens_its_jaws(tmp_path):
    """Strips drawn from a recorded NeedlePick episode sit where PyBullet had the wrist, blades spread by the jaw."""
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401
    from surrol_data.evaluation.rollout import rollout
    from surrol_data.viz.instrument import episode_instrument_strips, psm_rcm_positions

    env = gym.make("SurRoL/NeedlePick-v0")
    traj = rollout(env, "oracle", 3)
    rcms = psm_rcm_positions("SurRoL/NeedlePick-v0")
    assert len(rcms) == 1 and len(psm_rcm_positions("SurRoL/BiPegTransfer-v0")) == 2
    assert psm_rcm_positions("SurRoL/ECMReach-v0") is None
    last = episode_instrument_strips(traj.observation[-1:], 0, rcms[0])[0]
    wrist_pitch, _ = env.unwrapped.psm.link_pose_world(4)
    wrist_yaw, _ = env.unwrapped.psm.link_pose_world(5)
    np.testing.assert_allclose(last[0][1], wrist_pitch, atol=1e-6)
    np.testing.assert_allclose(last[1][1], wrist_yaw, atol=1e-6)
    spread = [np.linalg.norm(s[2][1] - s[3][1]) for s in episode_instrument_strips(traj.observation, 0, rcms[0])]
    jaw = traj.jaw_angle[:, 0]
    assert spread[int(np.argmax(jaw))] > spread[int(np.argmin(jaw))] + 0.002   # open blades ≥ 2 mm further apart
    env.close()
    path = save_rrd(tmp_path / "inst.rrd", [("oracle", traj, {"source": "script"})], rcm_positions=rcms)
    rows = [ch.to_record_batch() for ch in _chunks(path) if ch.entity_path == "/world/oracle/arm0/instrument"
            and not ch.is_static]
    assert sum(len(rb.column("LineStrips3D:strips").to_pylist()) for rb in rows) == len(traj) + 1


def test_view_serves_the_web_viewer(tmp_path):
    """`view --web` without a port, while Rerun's default ports (9090, 9876) are taken: it picks free ones, and the
    address it prints is the viewer's page connected to its own data server (not a page that shows nothing)."""
    import re
    import socket
    import urllib.request

    from surrol_data.collect.script_source import collect_script

    collect_script("NeedleReach", 1, tmp_path / "ds", progress=False)
    squatters = []
    for port in (9090, 9876):   # another viewer's servers, as a second `view --web` would meet them
        s = socket.socket()
        try:
            s.bind(("", port))
            s.listen()
            squatters.append(s)
        except OSError:
            s.close()   # taken already: all the better
    proc = subprocess.Popen([sys.executable, "-m", "surrol_data.cli", "view", str(tmp_path / "ds"), "--web",
                             "--no-open-browser"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "RERUN_ANALYTICS": "off", "COLUMNS": "300"})
    try:
        printed = []
        for line in proc.stdout:   # progress notes first, then the address (or the end of the output)
            printed.append(line)
            if "http://" in line:
                break
        found = re.search(r"http://localhost:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F[^%]+%3A(\d+)%2Fproxy", printed[-1])
        assert found, "".join(printed)
        web_port, grpc_port = int(found[1]), int(found[2])
        assert {web_port, grpc_port}.isdisjoint({9090, 9876})
        page = urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10).read().decode()
        assert "<html" in page.lower() and "rerun" in page.lower()   # it answered before the address was printed
        with socket.create_connection(("127.0.0.1", grpc_port), timeout=10):
            pass   # and its data server listens
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        for s in squatters:
            s.close()


def test_view_web_port_taken_is_a_clear_error(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("", 0))
        s.listen()
        taken = s.getsockname()[1]
        run = subprocess.run([sys.executable, "-m", "surrol_data.cli", "view", str(tmp_path / "any"), "--web",
                              "--web-port", str(taken), "--no-open-browser"], capture_output=True, text=True,
                             timeout=300, env={**os.environ, "COLUMNS": "300"})
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert f"--web-port {taken} is taken" in " ".join((run.stdout + run.stderr).split())

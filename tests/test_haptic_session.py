"""Haptic sessions end to end: real PyBullet scene, real lerobot dataset, devices through the real mapping."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from libhd_standin_build import build_libhd, oracle_device_frames, write_script
from surrol_data.cli import app
from surrol_data.collect.devices import DeviceError
from surrol_data.collect.devices.keyboard import KeyboardDevice, KeyTracker, PyBulletKeys
from surrol_data.collect.devices.trace import read_trace, trace_path
from surrol_data.collect.haptic_source import collect_haptic
from surrol_data.datasets.reader import DatasetReader

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture()
def touch_standin(tmp_path, monkeypatch):
    """A stand-in libHD serving the NeedlePick (seed 0) oracle played through the mapping, with a clutch re-centre."""
    lib = build_libhd(tmp_path)
    frames, actions, success = oracle_device_frames("NeedlePick", seed=0, horizon=150, clutch_steps=range(5, 8))
    assert success
    monkeypatch.setenv("LIBHD_STANDIN_SCRIPT", str(write_script(tmp_path / "script.txt", {"default": frames})))
    monkeypatch.delenv("LIBHD_STANDIN_UNPLUG_AFTER", raising=False)
    return lib, frames, actions


def test_standin_libhd_drives_a_needlepick_episode_into_a_dataset(tmp_path, touch_standin):
    lib, frames, actions = touch_standin
    out = tmp_path / "touch_ds"
    result = collect_haptic("NeedlePick", 1, out, device="touch", operator_id="standin", skill="expert", library=lib,
                            realtime=False, rerun_live=str(tmp_path / "live.rrd"), progress=False)
    assert (result.kept, result.attempts, result.ended_by) == (1, 1, "done")

    reader = DatasetReader(out)
    row = reader.episodes.iloc[0]
    assert (row["source"], row["device"], row["operator_id"], row["skill"]) == ("haptic", "touch", "standin", "expert")
    assert row["success"] and not row["operator_simulated"] and row["clutch_uses"] == 1 and row["jaw_closures"] == 1
    settings = json.loads(row["device_settings"])
    assert settings["devices"][0]["mapping"]["motion_scale"] == 0.5 and settings["devices"][0]["name"] == "touch"
    traj = reader.trajectory(0)
    np.testing.assert_array_equal(traj.action, actions)   # frames → ctypes → mapping → env, bit for bit
    assert traj.flags["clutch"][5:8].all() and traj.flags["clutch"].sum() == 3
    assert traj.flags["jaw_button"].any()

    trace = read_trace(trace_path(out, 0))   # the device trace saved next to the dataset
    assert trace.seed == 0 and trace.meta["skill"] == "expert"
    np.testing.assert_array_equal(trace.frames[0][:, :7], np.array([f.to_row() for f in frames])[:, :7])
    assert (tmp_path / "live.rrd").stat().st_size > 1000


def test_unplugged_device_keeps_finished_episodes_and_the_dataset_appends(tmp_path, touch_standin, monkeypatch):
    lib, frames, actions = touch_standin
    out = tmp_path / "ds"
    # the first attempt completes; the cable is pulled a few frames into the second
    monkeypatch.setenv("LIBHD_STANDIN_UNPLUG_AFTER", str(len(frames) + 4))
    with pytest.raises(DeviceError, match=r"stopped answering.*1 finished episode\(s\).*saved"):
        collect_haptic("NeedlePick", 2, out, device="touch", skill="novice", library=lib, realtime=False,
                       progress=False)
    assert len(DatasetReader(out)) == 1
    # a second session appends: the recorded trace replayed into the same dataset gives the same episode
    result = collect_haptic("NeedlePick", 1, out, device="replay", trace=out, append=True, progress=False)
    assert result.kept == 1
    reader = DatasetReader(out)
    assert list(reader.episodes["device"]) == ["touch", "replay"]
    assert list(reader.episodes["skill"]) == ["novice", "novice"]   # the replay carries the operator over
    np.testing.assert_array_equal(reader.trajectory(0).action, reader.trajectory(1).action)


def test_session_keys_redo_discard_and_quit_with_realtime_pacing(tmp_path):
    down, trig = PyBulletKeys.KEY_IS_DOWN, PyBulletKeys.KEY_WAS_TRIGGERED

    class Window:   # injected GUI key events; the session and the device each poll once per step
        def __init__(self, script):
            self.script = list(script)

        def getKeyboardEvents(self):   # noqa: N802
            return self.script.pop(0) if self.script else {}

    press = lambda key: {key if isinstance(key, int) else ord(key): down | trig}  # noqa: E731
    # attempt 1: redo at its 2nd step; attempt 2 (same seed): discard at its 2nd step; attempt 3 runs to the horizon
    window = Window([{}, {}, press("r"), {}, {}, press("f")])
    dev = KeyboardDevice(KeyTracker(PyBulletKeys(window)))
    t0 = time.monotonic()
    result = collect_haptic("NeedleReach", 1, tmp_path / "ds", device=[dev], operator_id="kb", skill="novice",
                            max_steps=4, keep_failures=True, progress=False)
    assert (result.redone, result.discarded, result.kept, result.seeds) == (1, 1, 1, [1])
    assert time.monotonic() - t0 > 4 * 0.2   # human devices are paced at the control period
    row = DatasetReader(tmp_path / "ds").episodes.iloc[0]
    assert row["device"] == "keyboard" and row["episode_steps"] == 4 and row["duration_s"] >= 3 * 0.2

    window = Window([press(27)])   # Esc: end the session at once
    result = collect_haptic("NeedleReach", 3, tmp_path / "ds", device=[KeyboardDevice(KeyTracker(PyBulletKeys(window)))],
                            max_steps=4, append=True, progress=False)
    assert result.ended_by == "operator" and result.kept == 0
    assert len(DatasetReader(tmp_path / "ds")) == 1


def test_cli_simulated_operator_session_and_its_replay(tmp_path):
    runner = CliRunner()
    recorded, replayed = tmp_path / "operator", tmp_path / "replayed"
    r = runner.invoke(app, ["collect", "--source", "haptic", "--device", "operator", "--skill", "expert",
                            "--operator-id", "sim-e1", "--task", "NeedlePick", "--num-episodes", "2", "--out", str(recorded)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["collect", "--source", "haptic", "--device", "replay", "--trace", str(recorded),
                            "--task", "NeedlePick", "--num-episodes", "2", "--out", str(replayed)])
    assert r.exit_code == 0, r.output
    a, b = DatasetReader(recorded), DatasetReader(replayed)
    assert len(a) == len(b) == 2
    ea, eb = a.episodes, b.episodes
    assert list(ea["device"]) == ["simulated-operator"] * 2 and list(eb["device"]) == ["replay"] * 2
    assert ea["operator_simulated"].all() and eb["operator_simulated"].all()
    assert list(eb["operator_id"]) == ["sim-e1"] * 2 and list(eb["seed"]) == list(ea["seed"])
    assert list(ea["success"]) == list(eb["success"]) == [True, True]
    for ep in range(2):
        ta, tb = a.trajectory(ep), b.trajectory(ep)
        np.testing.assert_array_equal(ta.action, tb.action)
        np.testing.assert_array_equal(ta.success, tb.success)
    r = runner.invoke(app, ["info", str(recorded)], env={"COLUMNS": "140"})
    assert r.exit_code == 0 and "Proficiency by source and skill" in r.output and "expert" in r.output


def test_cli_haptic_errors_are_clear(tmp_path):
    runner = CliRunner()
    r = runner.invoke(app, ["collect", "--source", "haptic", "--device", "operator", "--task", "NeedlePick",
                            "--num-episodes", "1", "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "--skill expert or --skill novice" in r.output
    r = runner.invoke(app, ["collect", "--source", "haptic", "--device", "touch", "--task", "NeedlePick",
                            "--num-episodes", "1", "--out", str(tmp_path / "y"), "--mapping", "motion_scale=fast"])
    assert r.exit_code == 2 and "not a number" in r.output


def _no_env(*args, **kwargs):
    raise AssertionError("the env was made before the device was found")


def test_a_touch_that_is_not_there_is_said_before_the_env_starts_and_no_folder_is_claimed(tmp_path, monkeypatch):
    """No OpenHaptics on the machine: one error naming what to install, before any env or dataset (the start-up
    took 22 s before), and no "episodes are saved in <a folder that does not exist>"."""
    import ctypes.util

    monkeypatch.delenv("SURROL_LIBHD", raising=False)
    if ctypes.util.find_library("HD"):
        pytest.skip("this machine has a libHD: the missing-SDK path cannot be taken here")
    monkeypatch.setattr("surrol_data.collect.haptic_source.make_env", _no_env)
    out = tmp_path / "touch_try"
    r = CliRunner().invoke(app, ["collect", "--source", "haptic", "--device", "touch", "--task", "NeedlePick",
                                 "--num-episodes", "1", "--out", str(out)])
    said = " ".join(r.output.split())
    assert r.exit_code == 2, said
    assert "device: cannot load libHD" in said and "OpenHaptics" in said and "SURROL_LIBHD" in said
    assert "saved in" not in said and not out.exists()


def test_an_unplugged_touch_is_found_before_the_env_starts(tmp_path, touch_standin, monkeypatch):
    lib, _, _ = touch_standin   # its script names only the default device: a stylus named Right is not plugged in
    monkeypatch.setattr("surrol_data.collect.haptic_source.make_env", _no_env)
    with pytest.raises(DeviceError, match="cannot initialise Touch device Right.*plugged in"):
        collect_haptic("NeedlePick", 1, tmp_path / "x", device="touch", sides=["right"], library=lib, progress=False)
    assert not (tmp_path / "x").exists()


def test_a_device_lost_before_any_episode_claims_no_dataset(tmp_path, touch_standin, monkeypatch):
    lib, frames, _ = touch_standin
    monkeypatch.setenv("LIBHD_STANDIN_UNPLUG_AFTER", "4")   # pulled out during the first attempt
    out = tmp_path / "ds"
    with pytest.raises(DeviceError, match=r"stopped answering.*nothing was recorded") as caught:
        collect_haptic("NeedlePick", 1, out, device="touch", library=lib, realtime=False, progress=False)
    assert "saved in" not in str(caught.value) and not out.exists()


@pytest.mark.slow
def test_sigkill_loses_at_most_the_episode_in_progress(tmp_path):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "surrol_data.cli", "collect", "--source", "haptic", "--device", "operator",
           "--skill", "novice", "--operator-id", "n1", "--task", "NeedlePick", "--num-episodes", "50", "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    info = out / "meta" / "info.json"
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            if info.exists() and json.loads(info.read_text() or "{}").get("total_episodes", 0) >= 2:
                break
            time.sleep(0.2)
        else:
            pytest.fail("the session recorded fewer than 2 episodes in 240 s")
        durable = json.loads(info.read_text())["total_episodes"]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    from surrol_data.datasets.repair import repair

    repair(out)
    reader = DatasetReader(out)
    assert len(reader) >= durable   # every episode finished before the kill (checkpoint after each one)
    assert reader.episodes["success"].all()
    before = len(reader)
    r = CliRunner().invoke(app, ["collect", "--source", "haptic", "--device", "operator", "--skill", "novice",
                                 "--operator-id", "n1", "--task", "NeedlePick", "--num-episodes", "1", "--seed", "100",
                                 "--out", str(out), "--append"])
    assert r.exit_code == 0, r.output
    assert len(DatasetReader(out)) == before + 1

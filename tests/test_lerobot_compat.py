"""The lerobot internals the recorder relies on (surrol_data.datasets.lerobot_compat) are the ones checked.

These fail loudly on a lerobot release nobody checked: re-read each internal in
``surrol_data/datasets/lerobot_compat.py`` against the new source, then add the version to CHECKED_VERSIONS.
"""

import warnings

import pytest

from surrol_data.datasets import lerobot_compat
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.schema import frame_features
from test_recorder import OBS, GOAL, RECORDER_ARGS, assert_same, make_traj, provenance


def test_installed_lerobot_is_a_checked_version():
    installed = lerobot_compat.lerobot_version()
    assert installed in lerobot_compat.CHECKED_VERSIONS, (
        f"lerobot {installed} is installed; surrol_data's recorder was checked against "
        f"{lerobot_compat.CHECKED_VERSIONS}: re-check every internal in surrol_data/datasets/lerobot_compat.py")


def test_every_internal_relied_on_exists():
    assert lerobot_compat.missing_internals() == []


def test_untested_version_warns_once(monkeypatch):
    monkeypatch.setattr(lerobot_compat, "lerobot_version", lambda: "9.9.9")
    monkeypatch.setattr(lerobot_compat, "_warned", False)
    with pytest.warns(lerobot_compat.UntestedLerobotWarning, match="lerobot 9.9.9 is installed"):
        lerobot_compat.check_lerobot()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lerobot_compat.check_lerobot()  # once per process


def test_checkpoints_take_the_fast_path_and_keep_every_episode(tmp_path, monkeypatch):
    """With the checked lerobot a checkpoint never falls back to finalize + resume, and the files it leaves
    read back exactly."""
    from surrol_data.datasets.recorder import DatasetRecorder

    LeRobotDataset = lerobot_compat.lerobot_dataset_class()

    def no_resume(*args, **kwargs):
        raise AssertionError("checkpoint fell back to LeRobotDataset.resume: lerobot's writer state changed")

    trajs = [make_traj(i, 6 + i) for i in range(3)]
    with DatasetRecorder(tmp_path / "d", features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=1,
                         handle_signals=False, consolidate=False,   # the files the checkpoints write, as left
                         **RECORDER_ARGS) as rec:
        monkeypatch.setattr(LeRobotDataset, "resume", classmethod(no_resume))
        for i, t in enumerate(trajs):
            rec.record(t, provenance(i))
        assert rec.durable_episodes == 3
    monkeypatch.undo()
    reader = DatasetReader(tmp_path / "d")
    for i, t in enumerate(trajs):
        assert_same(reader.trajectory(i), t)
    assert list(reader.episodes["seed"]) == [100, 101, 102]  # provenance columns went through the wrapper
    assert len(list((tmp_path / "d" / "data" / "chunk-000").glob("file-*.parquet"))) == 3

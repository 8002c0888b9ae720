"""Integrity: an episode's provenance and video segment are sealed when recorded; an edit afterwards is reported
naming the episode, by ``validate`` and by every command that reads the dataset (filter, export, merge refuse it).
A haptic episode's device trace is checked against its provenance as well (it catches edits in unsealed datasets).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.collect import corruptions
from surrol_data.datasets.guard import require_valid
from surrol_data.datasets.reader import DatasetError
from surrol_data.datasets.validate import validate_dataset

from dataset_forgery import drop_seals


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """4 haptic episodes (operator e1, expert) with camera video and device traces, in two files each."""
    return corruptions.base_dataset(tmp_path_factory.mktemp("integrity") / "base", camera=True)


@pytest.fixture
def copy(base, tmp_path) -> Path:
    root = tmp_path / "copy"
    shutil.copytree(base, root)
    return root


def _first_meta(root: Path) -> Path:
    return sorted((root / "meta" / "episodes").rglob("*.parquet"))[0]


def _edit_provenance(root: Path, column: str, value, row: int = 1) -> None:
    """What a hand edit with pandas/pyarrow does: one value of one provenance column, nothing else."""
    path = _first_meta(root)
    table = pq.read_table(path)
    values = table.column(column).to_pylist()
    values[row] = value
    at = table.schema.get_field_index(column)
    pq.write_table(table.set_column(at, table.schema.field(column), pa.array(values, table.schema.field(column).type)),
                   path)


def _cheap(root: Path) -> list:
    return validate_dataset(root, check_reward=False, check_lerobot=False)


def test_a_recorded_dataset_is_sealed_and_valid(base):
    side = json.loads((base / "meta" / "surrol_data.json").read_text())
    assert side["seals"] == 1
    columns = pq.read_schema(_first_meta(base)).names
    assert {"seal/provenance", "seal/observation.images.front"} <= set(columns)
    assert _cheap(base) == []


@pytest.mark.parametrize("column, value", [("provenance/operator_id", "e2"), ("provenance/skill", "novice")])
def test_edited_provenance_is_reported_naming_the_episode(copy, column, value):
    _edit_provenance(copy, column, value)
    problems = [p for p in _cheap(copy) if p.check == "integrity"]
    said = [str(p) for p in problems]
    assert any("seal/provenance" in s and "episode(s) 1:" in s for s in said), said
    # the device trace of episode 1 says e1 / expert too
    assert any("episode_000001.npz" in s and column.removeprefix("provenance/") in s for s in said), said
    with pytest.raises(DatasetError, match=r"episode\(s\) 1: the provenance is not what was recorded"):
        require_valid(copy)


def test_trace_cross_check_catches_an_edit_in_an_unsealed_dataset(copy):
    """A dataset recorded before seals existed: its device traces still contradict an edited operator."""
    drop_seals(copy)
    assert _cheap(copy) == []  # unsealed is allowed (older datasets)
    _edit_provenance(copy, "provenance/operator_id", "e2", row=0)
    (problem,) = _cheap(copy)
    assert problem.check == "integrity" and problem.where == "meta/device_traces/episode_000000.npz"
    assert "episode 0" in problem.message and "operator_id: trace 'e1', provenance 'e2'" in problem.message


def test_sealed_dataset_without_its_seals_is_reported(copy):
    path = _first_meta(copy)
    table = pq.read_table(path)
    pq.write_table(table.drop_columns(["seal/provenance"]), path)
    said = " ".join(str(p) for p in _cheap(copy))
    assert "episode(s) 0, 1 have no seal" in said


def _other_recording(like: Path, out: Path) -> None:
    """A valid mp4 of another recording: same codec family, size, rate and length, other frames."""
    import av

    with av.open(str(like)) as src:
        stream = src.streams.video[0]
        n = sum(1 for p in src.demux(stream) if p.size)
        width, height = stream.codec_context.width, stream.codec_context.height
    rng = np.random.default_rng(123)
    with av.open(str(out), "w") as dst:
        video = dst.add_stream("libsvtav1", rate=5)
        video.width, video.height, video.pix_fmt = width, height, "yuv420p"
        for _ in range(n):
            frame = av.VideoFrame.from_ndarray(rng.integers(0, 255, (height, width, 3), dtype=np.uint8), format="rgb24")
            for packet in video.encode(frame):
                dst.mux(packet)
        for packet in video.encode():
            dst.mux(packet)


def test_video_from_another_recording_is_reported_naming_its_episodes(copy, tmp_path):
    from surrol_data.datasets.repair import _video_ok

    video = sorted((copy / "videos").rglob("*.mp4"))[0]
    _other_recording(video, tmp_path / "other.mp4")
    shutil.copyfile(tmp_path / "other.mp4", video)
    table = pq.read_table(_first_meta(copy))
    assert _video_ok(video, max(table.column("videos/observation.images.front/to_timestamp").to_pylist()))
    problems = [p for p in _cheap(copy) if p.check == "integrity"]
    assert [p.where for p in problems] == [str(video.relative_to(copy))]
    assert "episode(s) 0, 1: the camera frames in this file are not the ones recorded" in problems[0].message


def test_filter_export_and_merge_refuse_a_tampered_dataset_with_the_same_message(copy, tmp_path):
    _edit_provenance(copy, "provenance/skill", "novice")
    runner = CliRunner()
    runs = {
        "filter": ["filter", str(copy), "--out", str(tmp_path / "f"), "--where", 'skill == "novice"'],
        "export": ["export", str(copy), "--format", "robomimic", "--out", str(tmp_path / "e.hdf5")],
        "merge": ["merge", str(copy), "--out", str(tmp_path / "m")],
    }
    messages = {}
    for name, args in runs.items():
        run = runner.invoke(app, args)
        said = " ".join(run.output.split())
        assert run.exit_code == 2, (name, run.output)
        assert "episode(s) 1: the provenance is not what was recorded" in said, (name, said)
        messages[name] = said
    assert len(set(messages.values())) == 1
    assert not any((tmp_path / n).exists() for n in ("f", "e.hdf5", "m"))

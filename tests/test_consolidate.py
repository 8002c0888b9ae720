"""Datasets at scale (issue 30): a finished recording is a few large files, not one per checkpoint; a kill at any
moment of that rewrite loses no episode; filter / split copy a state-only dataset's stored rows instead of
recording every episode again, and the result is what the recorder would have written."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from surrol_data.datasets import consolidate
from surrol_data.datasets.reader import DATA_DIR, EPISODES_DIR, DatasetReader, parquet_files
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.schema import SIDECAR_PATH, frame_features

from test_recorder import GOAL, OBS, RECORDER_ARGS, assert_same, make_traj, provenance

REPO_ROOT = Path(__file__).resolve().parents[1]
STEPS = 5


def record(root: Path, first: int, count: int, *, append: bool = False, consolidate: bool = True) -> Path:
    with DatasetRecorder(root, features=None if append else frame_features(OBS, GOAL, 5, 1), append=append,
                         checkpoint_every=10, checkpoint_interval_s=None, consolidate=consolidate,
                         **RECORDER_ARGS) as rec:
        for i in range(first, first + count):
            rec.record(make_traj(i, STEPS), provenance(i))
    return root


def files(root: Path) -> tuple[list[str], list[str]]:
    return ([p.relative_to(root).as_posix() for p in parquet_files(root, DATA_DIR)],
            [p.relative_to(root).as_posix() for p in parquet_files(root, EPISODES_DIR)])


def assert_whole(root: Path, episodes: int, LeRobotDataset) -> None:
    """lerobot loads every episode; our reader gives each one back as recorded; the full check passes."""
    from surrol_data.datasets.validate import validate_dataset

    ds = LeRobotDataset("local/ds", root=root, video_backend="pyav")
    assert (ds.num_episodes, ds.num_frames) == (episodes, episodes * STEPS)
    assert ds[len(ds) - 1]["episode_index"].item() == episodes - 1
    reader = DatasetReader(root)
    for ep, traj in enumerate(reader.trajectories()):
        assert_same(traj, make_traj(ep, STEPS))
    assert list(reader.episodes["seed"]) == [100 + i for i in range(episodes)]
    assert validate_dataset(root, check_reward=False) == []


@pytest.fixture(scope="module")
def LeRobotDataset():
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset


def test_a_finished_recording_is_one_data_and_one_metadata_file(tmp_path, LeRobotDataset):
    root = record(tmp_path / "ds", 0, 30)   # a checkpoint every 10 episodes: three files of each kind on the way
    assert files(root) == (["data/chunk-000/file-000.parquet"], ["meta/episodes/chunk-000/file-000.parquet"])
    meta = pq.read_table(root / EPISODES_DIR / "chunk-000" / "file-000.parquet")
    assert pq.read_metadata(root / EPISODES_DIR / "chunk-000" / "file-000.parquet").num_row_groups == 1
    for column in ("data/chunk_index", "data/file_index", "meta/episodes/chunk_index", "meta/episodes/file_index"):
        assert set(meta.column(column).to_pylist()) == {0}, column
    # lerobot's layout of the frames: one row group per episode
    assert pq.read_metadata(root / "data" / "chunk-000" / "file-000.parquet").num_row_groups == 30
    assert not (root / consolidate.STAGING_DIR).exists()
    assert_whole(root, 30, LeRobotDataset)


def test_an_appending_session_consolidates_only_what_it_wrote(tmp_path, LeRobotDataset):
    root = record(tmp_path / "ds", 0, 30)
    before = (root / "data" / "chunk-000" / "file-000.parquet").read_bytes()
    record(root, 30, 20, append=True)
    assert files(root) == (["data/chunk-000/file-000.parquet", "data/chunk-000/file-001.parquet"],
                           ["meta/episodes/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-001.parquet"])
    assert (root / "data" / "chunk-000" / "file-000.parquet").read_bytes() == before   # not rewritten
    assert_whole(root, 50, LeRobotDataset)


def test_consolidating_an_older_dataset_keeps_every_episode(tmp_path, LeRobotDataset):
    """A dataset recorded one file per checkpoint (before consolidation existed) consolidated afterwards."""
    root = record(tmp_path / "ds", 0, 30, consolidate=False)
    assert len(files(root)[0]) == 3 and len(files(root)[1]) == 3
    assert consolidate.consolidate(root)
    assert files(root) == (["data/chunk-000/file-000.parquet"], ["meta/episodes/chunk-000/file-000.parquet"])
    assert_whole(root, 30, LeRobotDataset)
    assert not consolidate.consolidate(root)   # nothing left to gain: nothing changes


KILLED = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, {tests!r})
    from surrol_data.datasets import consolidate
    from test_consolidate import record

    real, calls = os.replace, [0]

    def replace(src, dst):   # the process dies (no cleanup of any kind) at the {at}th rename of the consolidation
        calls[0] += 1
        if calls[0] == {at}:
            os._exit(137)
        real(src, dst)

    class Os:   # os for the consolidation module alone: the journal and the sidecar still rename as usual
        def __getattr__(self, name):
            return getattr(os, name)

    Os.replace = staticmethod(replace)
    consolidate.os = Os()
    {body}
""")


def run_killed(tmp_path: Path, at: int, body: str) -> None:
    script = tmp_path / f"killed_{at}.py"
    script.write_text(KILLED.format(tests=str(Path(__file__).parent), at=at, body=body))
    done = subprocess.run([sys.executable, str(script)], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 137, done.stderr[-3000:]


# rename 1 commits the plan (a kill there leaves a half-built, uncommitted consolidation); renames 2-7 move the
# three data and three metadata files aside, renames 8-9 put the two new files in place
@pytest.mark.parametrize("at", [1, 4, 8])
def test_killed_mid_consolidation_then_any_command_repairs_with_every_episode(tmp_path, LeRobotDataset, at):
    from surrol_data.datasets.guard import require_valid

    root = record(tmp_path / "ds", 0, 30, consolidate=False)
    side = json.loads((root / SIDECAR_PATH).read_text())
    side["sessions"][-1].pop("ended_at")   # where the recorder consolidates: before it marks the session ended
    (root / SIDECAR_PATH).write_text(json.dumps(side))
    run_killed(tmp_path, at, f"consolidate.consolidate({str(root)!r})")
    assert consolidate.interrupted(root)
    said = []
    assert require_valid(root, said.append) == root
    assert "the consolidation of its files was interrupted" in said[0]
    assert any(("undone" if at == 1 else "completed") in line for line in said)
    assert not consolidate.interrupted(root)
    assert len(files(root)[0]) == (3 if at == 1 else 1)
    assert_whole(root, 30, LeRobotDataset)


def test_recorder_killed_while_consolidating_then_repair_keeps_every_episode(tmp_path, LeRobotDataset):
    from surrol_data.datasets.repair import repair

    root = tmp_path / "ds"
    run_killed(tmp_path, 5, f"record(__import__('pathlib').Path({str(root)!r}), 0, 30)")
    assert consolidate.interrupted(root)
    report = repair(root)
    assert report.consolidation.startswith("an interrupted consolidation of the files was completed")
    assert report.lines()[0] == report.consolidation
    assert files(root) == (["data/chunk-000/file-000.parquet"], ["meta/episodes/chunk-000/file-000.parquet"])
    assert_whole(root, 30, LeRobotDataset)
    assert "ended_at" in json.loads((root / SIDECAR_PATH).read_text())["sessions"][-1]


def test_reader_reads_only_the_row_groups_of_the_episodes_asked_for(tmp_path, monkeypatch):
    root = record(tmp_path / "ds", 0, 30)
    reader = DatasetReader(root)
    asked = []
    real = pq.ParquetFile.read_row_groups

    def spy(self, groups, *args, **kwargs):
        asked.append(list(groups))
        return real(self, groups, *args, **kwargs)

    monkeypatch.setattr(pq.ParquetFile, "read_row_groups", spy)
    trajs = reader.trajectories([17, 3, 29])
    assert asked == [[3, 17, 29]]
    for ep, traj in zip([17, 3, 29], trajs, strict=True):
        assert_same(traj, make_traj(ep, STEPS))


def test_filter_copies_the_stored_rows_as_the_recorder_would_write_them(tmp_path, monkeypatch, LeRobotDataset):
    """The table-by-table copy of a state-only dataset against the recorder's path (every episode recorded
    again): the same frames, metadata rows (statistics within float noise), stats.json and totals."""
    from surrol_data.datasets import bulk_copy
    from surrol_data.datasets.merge import filter_dataset
    from surrol_data.datasets.validate import validate_dataset

    src = record(tmp_path / "src", 0, 30)
    keep = [2, 5, 7, 11, 12, 19, 23, 29]
    fast = filter_dataset(src, tmp_path / "fast", None, episodes=keep, progress=False)
    monkeypatch.setattr(bulk_copy, "applies", lambda readers: False)
    slow = filter_dataset(src, tmp_path / "slow", None, episodes=keep, progress=False)

    def data(root):
        return pq.read_table(root / "data" / "chunk-000" / "file-000.parquet")

    assert data(fast).schema.equals(data(slow).schema, check_metadata=True)
    assert data(fast).equals(data(slow))
    assert pq.read_metadata(fast / "data" / "chunk-000" / "file-000.parquet").num_row_groups == len(keep)
    a = pq.read_table(fast / EPISODES_DIR / "chunk-000" / "file-000.parquet")
    b = pq.read_table(slow / EPISODES_DIR / "chunk-000" / "file-000.parquet")
    assert a.column_names == b.column_names and a.schema.equals(b.schema)
    for name in a.column_names:
        if name.startswith("stats/"):
            x = np.asarray(a.column(name).to_pylist(), np.float64)
            y = np.asarray(b.column(name).to_pylist(), np.float64)
            assert np.allclose(x, y, rtol=1e-9, atol=1e-9), name
        else:   # as text: a NaN equals a NaN there
            assert json.dumps(a.column(name).to_pylist()) == json.dumps(b.column(name).to_pylist()), name
    sa, sb = (json.loads((r / "meta" / "stats.json").read_text()) for r in (fast, slow))
    assert sa.keys() == sb.keys()
    for feature in sa:
        for stat in sa[feature]:
            assert np.allclose(sa[feature][stat], sb[feature][stat], rtol=1e-6, atol=1e-9), (feature, stat)
    ia, ib = (json.loads((r / "meta" / "info.json").read_text()) for r in (fast, slow))
    assert ia == ib
    side = json.loads((fast / SIDECAR_PATH).read_text())
    assert side["derived_from"]["episodes"][3] == {"episode": 3, "source_root": str(src.resolve()),
                                                   "source_episode": 11}
    assert side["seals"] == 1 and side["sessions"][-1]["started_at"] <= side["sessions"][-1]["ended_at"]
    assert validate_dataset(fast, check_reward=False) == []
    ds = LeRobotDataset("local/fast", root=fast, video_backend="pyav")
    assert (ds.num_episodes, ds.num_frames) == (len(keep), len(keep) * STEPS)
    for new, ep in enumerate(keep):
        assert_same(DatasetReader(fast).trajectory(new), make_traj(ep, STEPS))
    assert not bulk_copy.staging_folder(tmp_path / "fast").exists()


def test_copied_statistics_aggregate_as_lerobot_does(tmp_path):
    """bulk_copy.aggregate_stats (column by column, no lerobot import) against lerobot's aggregate_stats."""
    from lerobot.datasets.compute_stats import aggregate_stats as lerobot_aggregate

    from surrol_data.datasets.bulk_copy import aggregate_stats
    from surrol_data.datasets.reader import column_to_numpy

    root = record(tmp_path / "ds", 0, 12)
    meta = pq.read_table(root / EPISODES_DIR / "chunk-000" / "file-000.parquet")
    per_episode = [{} for _ in range(meta.num_rows)]
    for name in meta.column_names:
        if name.startswith("stats/"):
            _, feature, stat = name.split("/", 2)
            for row, value in enumerate(column_to_numpy(meta.column(name)).reshape(meta.num_rows, -1)):
                per_episode[row].setdefault(feature, {})[stat] = value
    expected, got = lerobot_aggregate(per_episode), aggregate_stats(meta)
    assert got.keys() == expected.keys()
    for feature in expected:
        assert got[feature].keys() == expected[feature].keys(), feature
        for stat, value in expected[feature].items():
            assert got[feature][stat].shape == value.shape and np.allclose(got[feature][stat], value, rtol=1e-12,
                                                                           atol=0), (feature, stat)


def test_lerobot_check_builds_the_arrow_schema_once_and_loads_the_same(tmp_path, monkeypatch, LeRobotDataset):
    import datasets

    from surrol_data.datasets.lerobot_compat import quick_parquet_load

    root = record(tmp_path / "ds", 0, 30)   # 30 row groups: 30 record batches for Hugging Face datasets
    calls = []
    schema = datasets.Features.arrow_schema

    def counted(self):
        calls.append(1)
        return schema.fget(self)

    monkeypatch.setattr(datasets.Features, "arrow_schema", property(counted))
    loaded = []
    for quick, cache in ((False, "hf_plain"), (True, "hf_quick")):   # a cache each: both really load the files
        monkeypatch.setattr(datasets.config, "HF_DATASETS_CACHE", tmp_path / cache)
        calls.clear()
        with quick_parquet_load() if quick else contextlib.nullcontext():
            ds = LeRobotDataset("local/ds", root=root, video_backend="pyav")
        loaded.append((len(calls), ds.hf_dataset.data.table))
    (plain_calls, plain), (quick_calls, quick) = loaded
    assert plain_calls >= 30 and quick_calls < 10, (plain_calls, quick_calls)
    assert quick.equals(plain)


def test_a_copy_that_fails_midway_leaves_no_output(tmp_path, monkeypatch):
    from surrol_data.datasets import bulk_copy
    from surrol_data.datasets.merge import filter_dataset

    src = record(tmp_path / "src", 0, 12)
    out = tmp_path / "out"

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(bulk_copy, "_write_metadata", disk_full)
    with pytest.raises(OSError, match="No space left"):
        filter_dataset(src, out, "skill == 'novice'", progress=False)
    assert not out.exists() and not bulk_copy.staging_folder(out).exists()
    monkeypatch.undo()
    bulk_copy.staging_folder(out).mkdir()   # what a SIGKILL mid-copy leaves: the next copy clears it
    (bulk_copy.staging_folder(out) / "dataset").mkdir()
    filter_dataset(src, out, "skill == 'novice'", progress=False)
    assert len(DatasetReader(out)) == 8 and not bulk_copy.staging_folder(out).exists()

"""``info`` checks what it shows — the metadata — without reading a frame or hashing the dataset (so it answers in
seconds at 10,000 episodes), and still refuses an edited provenance, a wrong count or a cut-short file."""

from __future__ import annotations

import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets import guard, validated_cache
from surrol_data.datasets.reader import DatasetError
from test_recorder import record_small_dataset


@pytest.fixture
def root(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return record_small_dataset(tmp_path / "ds", 4)


def _no_frames_read(monkeypatch):
    """Reading any data file's rows, or hashing the dataset, fails the test."""
    read_table, parquet_file = pq.read_table, pq.ParquetFile

    def guarded_read_table(source, *args, **kwargs):
        assert "/data/" not in str(source), f"a frame was read: {source}"
        return read_table(source, *args, **kwargs)

    def guarded_parquet_file(source, *args, **kwargs):
        assert "/data/" not in str(source), f"a data file was opened: {source}"
        return parquet_file(source, *args, **kwargs)

    def no_digest(root):
        raise AssertionError("the dataset was hashed")

    monkeypatch.setattr(pq, "read_table", guarded_read_table)
    monkeypatch.setattr(pq, "ParquetFile", guarded_parquet_file)
    monkeypatch.setattr(validated_cache, "dataset_digest", no_digest)


def test_the_metadata_check_reads_no_frame_and_hashes_nothing(root, monkeypatch):
    before = sorted((p.relative_to(root), p.stat().st_mtime_ns) for p in root.rglob("*"))
    _no_frames_read(monkeypatch)
    assert guard.require_valid(root, frames=False) == root
    assert sorted((p.relative_to(root), p.stat().st_mtime_ns) for p in root.rglob("*")) == before


def test_the_metadata_check_refuses_an_edited_provenance(root, monkeypatch):
    path = sorted((root / "meta" / "episodes").rglob("*.parquet"))[0]
    table = pq.read_table(path)
    i = table.column_names.index("provenance/operator_id")
    table = table.set_column(i, "provenance/operator_id", pa.array(["e2"] * table.num_rows, pa.string()))
    pq.write_table(table, path)
    _no_frames_read(monkeypatch)
    with pytest.raises(DatasetError, match=r"episode\(s\) 0, 1, 2, 3: the provenance is not what was recorded"):
        guard.require_valid(root, frames=False)


def test_the_metadata_check_counts_frames_from_the_footers(root):
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["total_frames"] += 1
    info_path.write_text(json.dumps(info))
    with pytest.raises(DatasetError, match=f"says {info['total_frames']}, the data files hold 24 frames"):
        guard.require_valid(root, frames=False)


def test_info_refuses_a_cut_short_data_file_naming_the_repair(root):
    path = sorted((root / "data").rglob("*.parquet"))[0]
    path.write_bytes(path.read_bytes()[:-100])
    run = CliRunner().invoke(app, ["info", str(root)])
    said = " ".join(run.output.split())
    assert run.exit_code == 2, run.output
    assert "has no parquet footer" in said and f"surrol-data repair {root}" in said

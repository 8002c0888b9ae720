"""The commands' own check of their input is skipped for bytes that already passed it, and only for those."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from surrol_data.datasets import guard
from surrol_data.datasets.reader import DatasetError
from surrol_data.datasets.validated_cache import cache_dir, dataset_digest
from test_recorder import record_small_dataset


def test_checked_bytes_are_not_checked_again_and_any_edit_is(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    root = record_small_dataset(tmp_path / "ds", 3)
    before = sorted(p.relative_to(root) for p in root.rglob("*"))
    assert guard.require_valid(root) == root
    assert (cache_dir() / dataset_digest(root)).is_file()
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before   # nothing written into the dataset

    import surrol_data.datasets.validate as validate

    def must_not_run(*args, **kwargs):
        raise AssertionError("checked again")

    monkeypatch.setattr(validate, "validate_dataset", must_not_run)
    assert guard.require_valid(root) == root   # the same bytes: not checked again
    monkeypatch.undo()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    path = sorted((root / "meta" / "episodes").rglob("*.parquet"))[0]
    table = pq.read_table(path)
    i = table.column_names.index("provenance/operator_id")
    table = table.set_column(i, "provenance/operator_id", pa.array(["e2"] * table.num_rows, pa.string()))
    pq.write_table(table, path)
    with pytest.raises(DatasetError, match="seal"):   # an edit after the check is checked, and caught
        guard.require_valid(root)

"""``info`` remembers its answer by the dataset's content digest (seconds at 10,000 episodes instead of ~30 s of
CPU), and only by it: any edited byte is checked and reported again, a killed recording is still found first,
nothing is written into the dataset, and a cache folder that cannot be written only costs the memory."""

from __future__ import annotations

import hashlib
import os
import re
import shutil

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets import info as info_module
from surrol_data.datasets import info_cache, validate
from surrol_data.datasets.info_cache import info_cache_dir
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.validated_cache import dataset_digest
from test_recorder import RECORDER_ARGS, make_traj, provenance, record_small_dataset


@pytest.fixture
def root(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return record_small_dataset(tmp_path / "ds", 6)


def _files(root):
    """Every file's bytes digest and modification time: what 'nothing written' means."""
    return {str(p.relative_to(root)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def _info(root):
    run = CliRunner().invoke(app, ["info", str(root)], terminal_width=200)
    return run.exit_code, run.output


def _must_not_run(*args, **kwargs):
    raise AssertionError("checked or summarised again")


def test_the_same_bytes_are_answered_from_memory_and_nothing_is_written(root, monkeypatch):
    before = _files(root)
    code, first = _info(root)
    assert code == 0, first
    assert (info_cache_dir() / f"{dataset_digest(root)}.json").is_file()
    monkeypatch.setattr(validate, "validate_dataset", _must_not_run)
    monkeypatch.setattr(info_module, "info_facts", _must_not_run)
    monkeypatch.setattr(info_cache, "info_facts", _must_not_run)
    monkeypatch.setattr(info_module, "DatasetReader", _must_not_run)
    code, again = _info(root)
    assert code == 0 and again == first   # the very same answer, with no check or summary computed
    assert "Proficiency by source and skill" in again and re.search(r"episodes\s*│\s*6\b", again), again
    assert _files(root) == before


def test_an_edit_after_info_answered_is_checked_and_reported(root):
    assert _info(root)[0] == 0
    path = sorted((root / "meta" / "episodes").rglob("*.parquet"))[0]
    st = path.stat()
    table = pq.read_table(path)
    i = table.column_names.index("provenance/operator_id")
    table = table.set_column(i, "provenance/operator_id", pa.array(["op9"] * table.num_rows, pa.string()))
    pq.write_table(table, path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))   # an edit that keeps the file's time is still an edit
    code, said = _info(root)
    said = " ".join(said.split())
    assert code == 2 and "the provenance is not what was recorded" in said, said
    assert "episode(s) 0, 1, 2, 3, 4 (+1 more)" in said, said


def test_bit_rot_after_info_answered_is_refused_naming_the_repair(root):
    assert _info(root)[0] == 0
    path = sorted((root / "data").rglob("*.parquet"))[0]
    path.write_bytes(path.read_bytes()[:-50])
    before = _files(root)
    code, said = _info(root)
    said = " ".join(said.split())
    assert code == 2 and "has no parquet footer" in said and f"surrol-data repair {root}" in said, said
    assert _files(root) == before   # refused, not "repaired" in place


def test_a_killed_recording_is_found_before_the_memory_is_asked(root, tmp_path):
    assert _info(root)[0] == 0
    rec = DatasetRecorder(root, append=True, checkpoint_every=100, handle_signals=False, **RECORDER_ARGS)
    rec.open()
    for i in range(6, 8):
        rec.record(make_traj(i, 6), provenance(i))
    killed = tmp_path / "killed"
    shutil.copytree(root, killed)   # the files as they are mid-session
    rec.close()
    (killed / ".surrol_data.lock").unlink()   # the kernel drops a dead process's lock
    code, said = _info(killed)
    assert code == 0 and "killed recording" in said and "repairing it" in said, said
    assert re.search(r"episodes\s*│\s*8\b", said), said


def test_a_cache_folder_that_cannot_be_written_only_costs_the_memory(root, tmp_path, monkeypatch):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    first = _info(root)
    assert first[0] == 0 and _info(root) == first


def test_the_smoothness_reads_each_data_file_once(root, monkeypatch):
    """LDLJ needs the tip columns: one pass over the data files for every group, not one pass per group."""
    reads = []
    read_table = pq.read_table

    def counting(source, *args, **kwargs):
        if "/data/" in str(source):
            reads.append(str(source))
        return read_table(source, *args, **kwargs)

    monkeypatch.setattr(pq, "read_table", counting)
    facts = info_module.info_facts(root)
    assert len({(g["source"], g["skill"]) for g in facts["by_skill"] if g["success_rate"] > 0}) >= 2
    assert len(reads) == len(set(reads)) == len(list((root / "data").rglob("*.parquet")))

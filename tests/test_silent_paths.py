"""The paths where a command used to end in a traceback, give the wrong cause, or present an unchecked fact as
checked: a folder literally named ``$HOME``, ``--out`` a dangling symbolic link, a recording killed before its
LeRobot files existed on a read-only disk, frames relabelled to another episode, what ``info`` checked, and the info
cache's digest."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

import private_mounts
from surrol_data.cli import app
from surrol_data.collect import corruptions
from surrol_data.datasets.reader import DatasetReader

runner = CliRunner()


def _said(result) -> str:
    """The output as one line of words, table borders left out (rich wraps a table's cells)."""
    return " ".join(result.output.replace("│", " ").split())


def _no_traceback(result) -> bool:
    return (result.exception is None or isinstance(result.exception, SystemExit)) and "Traceback" not in result.output


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return corruptions.base_dataset(tmp_path_factory.mktemp("silent") / "base", camera=False)


@pytest.fixture
def copy(base, tmp_path) -> Path:
    root = tmp_path / "copy"
    shutil.copytree(base, root)
    return root


@pytest.mark.slow   # three recordings through the CLI
def test_a_folder_literally_named_home_takes_collect_append_and_merge(tmp_path):
    home = tmp_path / "$HOME"
    home.mkdir()
    collect = ["collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "1", "--max-steps", "15",
               "--keep-failures", "--out", str(home / "ds")]
    for extra in ([], ["--append"]):
        run = runner.invoke(app, collect + extra)
        assert run.exit_code == 0 and _no_traceback(run), run.output   # lerobot looked for it under the real $HOME
    run = runner.invoke(app, ["merge", str(home / "ds"), "--out", str(home / "merged")])
    assert run.exit_code == 0 and _no_traceback(run), run.output
    assert len(DatasetReader(home / "merged")) == 2


def test_merge_into_a_dangling_link_writes_where_it_points(base, tmp_path):
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "target")
    run = runner.invoke(app, ["merge", str(base), "--out", str(link)])
    assert run.exit_code == 0 and _no_traceback(run), run.output   # NotADirectoryError before
    assert len(DatasetReader(link)) == len(DatasetReader(base))
    assert (tmp_path / "target" / "meta" / "info.json").exists()


_KILLED_BEFORE_CREATION = """
import os, sys
from surrol_data.collect.corruptions import GOAL, OBS, _trajectory
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.schema import frame_features
rec = DatasetRecorder(sys.argv[1], features=frame_features(OBS, GOAL, 5, 1), task="NeedleReach",
                      env_id="SurRoL/NeedleReach-v0", task_description="reach the needle", handle_signals=False)
rec.open()
for i in range(2):
    rec.record(_trajectory(i, 6, False), {"source": "script", "device": "none", "skill": "scripted", "seed": i})
os._exit(0)   # killed: the LeRobot dataset is created at the first checkpoint, which never came
"""

_ON_READ_ONLY = """
import json, sys
from typer.testing import CliRunner
from surrol_data.cli import app
root, out = sys.argv[1], sys.argv[2]
runner = CliRunner()
results = {}
for name, args in (("export", ["export", root, "--format", "robomimic", "--out", out]),
                   ("validate", ["validate", root, "--no-reward", "--no-lerobot"]),
                   ("append", ["collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "1",
                               "--max-steps", "15", "--out", root, "--append"])):
    r = runner.invoke(app, args)
    results[name] = {"code": r.exit_code, "output": " ".join(r.output.split()),
                     "exception": None if r.exception is None or isinstance(r.exception, SystemExit) else repr(r.exception)}
print("RESULTS " + json.dumps(results))
"""


@pytest.mark.slow   # a recording in a subprocess, three commands in a mount namespace
def test_a_recording_killed_before_its_lerobot_files_on_a_read_only_disk(tmp_path):
    why = private_mounts.skip_reason()
    if why:
        pytest.skip(why)
    disk = tmp_path / "disk"
    root = disk / "demos"
    disk.mkdir()
    script = tmp_path / "killed.py"
    script.write_text(_KILLED_BEFORE_CREATION)
    subprocess.run([sys.executable, str(script), str(root)], check=True, timeout=300)
    assert not (root / "meta" / "info.json").exists() and (root / ".surrol_data_journal").is_dir()
    reader = tmp_path / "read.py"
    reader.write_text(_ON_READ_ONLY)
    run = private_mounts.run(f"mount --bind '{disk}' '{disk}' && mount -o remount,ro,bind '{disk}' && "
                             f"'{sys.executable}' '{reader}' '{root}' '{tmp_path / 'out.hdf5'}'", timeout=600)
    line = next(x for x in run.stdout.splitlines() if x.startswith("RESULTS "))
    results = json.loads(line.removeprefix("RESULTS "))
    assert all(r["exception"] is None for r in results.values()), results
    assert results["export"]["code"] == 0, results["export"]   # it read a repaired copy; then said info.json missing
    assert (tmp_path / "out.hdf5").exists()
    assert "info.json is missing" not in results["validate"]["output"]
    assert "killed" in results["validate"]["output"] and "copy it to a writable folder" in results["validate"]["output"]
    assert results["append"]["code"] == 2 and "cannot be written here" in results["append"]["output"], results


def _edit_data(root: Path, change) -> None:
    path = sorted((root / "data").rglob("*.parquet"))[-1]
    table = pq.read_table(path)
    pq.write_table(change(table), path)


def test_info_on_frames_relabelled_to_another_episode_is_one_line(copy):
    def relabel(table: pa.Table) -> pa.Table:   # the last episode's frames now say they are the one before's
        episodes = table.column("episode_index").to_numpy().copy()
        episodes[episodes == episodes.max()] = episodes.max() - 1
        at = table.column_names.index("episode_index")
        return table.set_column(at, table.schema.field(at), pa.array(episodes, table.schema.field(at).type))

    _edit_data(copy, relabel)
    run = runner.invoke(app, ["info", str(copy)])
    assert run.exit_code == 2 and _no_traceback(run), run.output   # KeyError before
    assert "frames are damaged" in _said(run) and "surrol-data validate" in _said(run)


def test_info_says_what_it_checked_and_what_not(copy, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    def forge(table: pa.Table) -> pa.Table:   # every frame succeeds: a fact info does not check
        at = table.column_names.index("next.success")
        field = table.schema.field(at)
        flat = pa.array(np.ones(table.num_rows, bool))
        values = pa.FixedSizeListArray.from_arrays(flat, 1) if pa.types.is_fixed_size_list(field.type) else flat
        return table.set_column(at, field, values.cast(field.type))

    _edit_data(copy, forge)
    run = runner.invoke(app, ["info", str(copy)], terminal_width=200)
    said = _said(run)
    assert run.exit_code == 0, run.output
    assert "checked metadata and seals" in said and "not the frames: run `surrol-data validate`" in said
    assert "as recorded in the episodes' metadata" in said


def test_the_info_cache_remembers_only_the_bytes_it_read(copy, tmp_path, monkeypatch):
    from surrol_data.datasets import info_cache
    from surrol_data.datasets.validated_cache import dataset_digest

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    before = dataset_digest(copy)
    real = info_cache.info_facts

    def facts_then_change(root):
        facts = real(root)
        with open(Path(root) / "meta" / "surrol_data.json", "a") as fh:   # another process writes meanwhile
            fh.write(" ")
        return facts

    monkeypatch.setattr(info_cache, "info_facts", facts_then_change)
    info_cache.checked_info(copy)
    assert not (info_cache.info_cache_dir() / f"{before}.json").exists()
    monkeypatch.setattr(info_cache, "info_facts", real)
    info_cache.checked_info(copy)   # unchanged bytes now: remembered
    assert (info_cache.info_cache_dir() / f"{dataset_digest(copy)}.json").exists()

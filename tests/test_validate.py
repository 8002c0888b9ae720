"""``validate``: a clean dataset passes; each kind of damage is caught with a message that locates it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from test_dataset_tools import make_dataset

from surrol_data.datasets.consolidate import write_one_row_group_per_episode as _write_one_row_group_per_episode
from surrol_data.datasets.validate import validate_dataset

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    root, _ = make_dataset(tmp_path_factory.mktemp("validate") / "reach")
    return root


@pytest.fixture
def broken(clean, tmp_path):
    """A fresh copy of the clean dataset to damage."""
    root = tmp_path / "reach"
    shutil.copytree(clean, root)
    return root


def _episodes_file(root: Path) -> Path:
    (path,) = sorted((root / "meta" / "episodes").rglob("*.parquet"))
    return path


def _data_file(root: Path) -> Path:
    (path,) = sorted((root / "data").rglob("*.parquet"))
    return path


def _rewrite_data(root: Path, column: str, change) -> None:
    """Apply ``change(values ndarray) -> ndarray`` to a data column, keeping one row group per episode."""
    path = _data_file(root)
    table = pq.read_table(path)
    col = table.column(column).combine_chunks()
    if pa.types.is_fixed_size_list(col.type):
        values = col.flatten().to_numpy().reshape(len(col), col.type.list_size).copy()
        new = pa.FixedSizeListArray.from_arrays(pa.array(change(values).reshape(-1), col.type.value_type),
                                                col.type.list_size)
    else:
        new = pa.array(change(col.to_numpy().copy()), col.type)
    table = table.set_column(table.schema.get_field_index(column), table.schema.field(column), new)
    _write_one_row_group_per_episode(table, path)


def test_clean_dataset_passes_every_check(clean):
    assert validate_dataset(clean) == []  # reward check with the real env, LeRobotDataset included


def test_a_disk_that_refuses_lerobots_cache_is_the_disks_error_not_a_finding(clean, monkeypatch):
    """LeRobot writes a cache under ~/.cache as it loads a dataset; that disk being full says nothing of the dataset:
    validate raises the disk's error (the CLI's one-line message) instead of calling the dataset unreadable."""
    import errno

    import surrol_data.datasets.writer as writer

    def full(*args, **kwargs):
        try:
            raise OSError(errno.ENOSPC, "No space left on device", "/root/.cache/huggingface/datasets/x.lock")
        except OSError as e:   # as HF datasets wraps it: an OSError without errno, the disk's one as its cause
            raise OSError("Cannot find data file. Original error:\n" + str(e)) from e

    monkeypatch.setattr(writer, "_lerobot_dataset_class", lambda: full)
    with pytest.raises(OSError) as raised:
        validate_dataset(clean, check_reward=False)
    assert raised.value.errno == errno.ENOSPC


def test_missing_provenance_column(broken):
    path = _episodes_file(broken)
    table = pq.read_table(path)
    pq.write_table(table.drop_columns(["provenance/skill"]), path)
    problems = validate_dataset(broken, check_lerobot=False)
    assert [p.check for p in problems] == ["provenance"]
    assert "provenance/skill" in problems[0].where and "missing" in problems[0].message


def test_wrong_provenance_type(broken):
    path = _episodes_file(broken)
    table = pq.read_table(path)
    i = table.schema.get_field_index("provenance/seed")
    table = table.set_column(i, pa.field("provenance/seed", pa.string()), pc.cast(table.column(i), pa.string()))
    pq.write_table(table, path)
    problems = validate_dataset(broken, check_lerobot=False)
    assert len(problems) == 1
    assert "provenance/seed" in problems[0].where and "has type string, expected int" in problems[0].message


def test_truncated_parquet(broken):
    path = _data_file(broken)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    problems = validate_dataset(broken)
    assert [(p.check, p.where) for p in problems] == [("parquet", "data/chunk-000/file-000.parquet")]
    assert "repair" in problems[0].message


def test_frame_with_nan(broken):
    def poison(values):
        values[20, 1] = np.nan  # episode 1 (15 frames per episode), frame 5
        return values

    _rewrite_data(broken, "observation.state", poison)
    problems = validate_dataset(broken, check_lerobot=False)
    messages = [str(p) for p in problems if p.check == "values"]
    assert any("column observation.state" in m and "NaN or inf at episode 1 frame 5" in m for m in messages), messages


def test_reward_inconsistent_with_goals(broken):
    def flip(values):
        values[33] = 0.0 if values[33] < -0.5 else -1.0  # episode 2, frame 3
        return values

    _rewrite_data(broken, "next.reward", flip)
    problems = validate_dataset(broken, check_lerobot=False)
    (reward,) = [p for p in problems if p.check == "reward"]
    assert "SurRoL/NeedleReach-v0" in reward.message and "episode 2 frame 3" in reward.message
    # the stored content hash also catches the changed frames
    assert any(p.where.endswith("content_hash") and "episode(s) 2" in p.message for p in problems)


def test_episode_count_mismatch(broken):
    info_path = broken / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["total_episodes"] += 1
    info_path.write_text(json.dumps(info))
    problems = validate_dataset(broken, check_lerobot=False)
    assert [(p.check, p.where) for p in problems] == [("counts", "meta/info.json total_episodes")]
    assert f"says {info['total_episodes']}, meta/episodes has {info['total_episodes'] - 1} rows" in problems[0].message


def test_chained_next_observation_and_lerobot_check(broken):
    def shift(values):
        values[7, 0] += 0.5  # episode 0 frame 7: s_{t+1} no longer the next frame's s_t
        return values

    _rewrite_data(broken, "next.observation.state", shift)
    (broken / "meta" / "tasks.parquet").unlink()  # lerobot cannot open it without its tasks table
    problems = validate_dataset(broken, check_reward=False)
    assert {"values", "lerobot", "tasks"} <= {p.check for p in problems}
    assert any("episode 0 frame 7" in str(p) for p in problems)


def test_not_a_dataset(tmp_path):
    problems = validate_dataset(tmp_path)
    assert [p.check for p in problems] == ["format"] and "meta/info.json is missing" in problems[0].message


def test_cli_exit_codes(clean, broken):
    path = _episodes_file(broken)
    pq.write_table(pq.read_table(path).drop_columns(["provenance/operator_id"]), path)
    cli = [sys.executable, "-m", "surrol_data.cli", "validate", "--no-lerobot", "--no-reward"]
    wide = {**os.environ, "COLUMNS": "250"}   # Rich folds a line at 80 columns, and a worker's tmp_path is longer
    bad = subprocess.run([*cli, str(broken)], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120, env=wide)
    assert bad.returncode == 1 and "provenance/operator_id" in bad.stdout and "1 problem(s)" in bad.stdout
    ok = subprocess.run([*cli, str(clean)], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120, env=wide)
    assert ok.returncode == 0 and "is a valid surrol_data dataset" in ok.stdout

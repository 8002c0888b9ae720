"""Nothing lost, nothing wrong accepted: journal + repair, the writer lock, duplicates, append seeds, the
validation fuzz, run directories. The full fuzz and the kill campaign are slow-marked
(``benchmarks/crash_safety.py`` runs the campaign with tables)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from surrol_data.collect import corruptions
from surrol_data.datasets.guard import require_valid
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.repair import repair
from surrol_data.datasets.validate import validate_dataset

REPO_ROOT = Path(__file__).resolve().parents[1]
ARGS = dict(task="NeedleReach", env_id="SurRoL/NeedleReach-v0", task_description="reach the needle")


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """A clean state-only dataset: 4 haptic episodes in two data files, with device traces."""
    return corruptions.base_dataset(tmp_path_factory.mktemp("crash") / "base", camera=False)


@pytest.fixture
def copy(base, tmp_path) -> Path:
    root = tmp_path / "copy"
    shutil.copytree(base, root)
    return root


def test_base_dataset_is_clean(base):
    assert validate_dataset(base, check_reward=False, check_lerobot=False) == []


FAST_CLASSES = ["fps changed", "actions x100", "task_index out of range", "stats.json mean altered",
                "traces swapped", "data files swapped", "provenance path length altered", "feature shape changed"]


@pytest.mark.parametrize("name", FAST_CLASSES)
def test_validate_and_commands_catch_damage(base, tmp_path, name):
    root = corruptions.damaged_copy(base, name, tmp_path / "damaged")
    problems = validate_dataset(root, check_reward=False, check_lerobot=False)
    assert problems, f"{name} passed silently"
    assert all(p.where and p.message for p in problems)
    with pytest.raises(DatasetError, match="is damaged"):  # what info/merge/filter/split/export/train run first
        require_valid(root)


def test_repair_salvages_episodes_after_a_damaged_first_file(copy):
    data = sorted((copy / "data").rglob("*.parquet"))
    data[0].write_bytes(data[0].read_bytes()[:100])  # episodes 0-1 are lost with it
    report = repair(copy)
    assert [ep for ep, _ in report.dropped] == [0, 1]
    assert all("unreadable" in why for _, why in report.dropped)
    assert (report.episodes_kept, report.episodes_salvaged) == (2, 2)
    reader = DatasetReader(copy)
    assert list(reader.episodes["seed"]) == [2, 3]
    # device traces were renamed with their episodes, and the repaired dataset is valid
    assert validate_dataset(copy, check_reward=False, check_lerobot=False) == []


def test_killed_recording_is_repaired_automatically_from_its_journal(base, tmp_path):
    """A recorder never closed (what SIGKILL leaves): its journal brings back every finished episode."""
    root = tmp_path / "live"
    shutil.copytree(base, root)
    trajs = [corruptions._trajectory(10 + i, 5, False) for i in range(3)]
    rec = DatasetRecorder(root, append=True, checkpoint_every=100, handle_signals=False, **ARGS)
    rec.open()
    for i, traj in enumerate(trajs):
        rec.record(traj, {"source": "script", "device": "none", "skill": "scripted", "seed": 10 + i})
    frozen = tmp_path / "killed"
    shutil.copytree(root, frozen)  # the files as they are mid-session
    rec.close()
    (frozen / ".surrol_data.lock").unlink()  # the kernel drops a dead process's lock
    notes: list[str] = []
    require_valid(frozen, notes.append)
    assert notes and "repairing" in notes[0]
    reader = DatasetReader(frozen)
    assert list(reader.episodes["seed"]) == [0, 1, 2, 3, 10, 11, 12]


def test_a_second_writer_gets_a_clear_error(copy):
    with DatasetRecorder(copy, append=True, handle_signals=False, **ARGS):
        with pytest.raises(DatasetError, match="being written by another process"):
            DatasetRecorder(copy, append=True, handle_signals=False, **ARGS).open()
        with pytest.raises(DatasetError, match="being written"):
            repair(copy)
    # released on close: a later writer proceeds
    with DatasetRecorder(copy, append=True, handle_signals=False, **ARGS):
        pass


def test_recording_without_any_episode_leaves_no_folder(tmp_path):
    root = tmp_path / "empty"
    features = DatasetReader  # noqa: F841 - (imports only)
    from surrol_data.datasets.schema import frame_features

    with DatasetRecorder(root, features=frame_features(7, 3, 5, 1), handle_signals=False, **ARGS):
        pass
    assert not root.exists()
    # a folder left by a recording killed before its first episode does not block a retry either
    rec = DatasetRecorder(root, features=frame_features(7, 3, 5, 1), handle_signals=False, **ARGS)
    rec.open()
    rec._lock.release()  # as after SIGKILL
    with DatasetRecorder(root, features=frame_features(7, 3, 5, 1), handle_signals=False, **ARGS) as again:
        again.record(corruptions._trajectory(0, 4, False), {"source": "script", "device": "none",
                                                            "skill": "scripted", "seed": 0})
    assert len(DatasetReader(root)) == 1


def test_merge_refuses_duplicates_unless_dropped(base, tmp_path):
    from surrol_data.datasets.merge import merge_datasets

    with pytest.raises(DatasetError, match="exact copies"):
        merge_datasets(tmp_path / "twice", [base, base], progress=False)
    assert not (tmp_path / "twice").exists()
    out = merge_datasets(tmp_path / "once", [base, base], progress=False, drop_duplicates=True)
    reader = DatasetReader(out)
    assert len(reader) == 4
    assert list(reader.episodes["content_hash"]) == list(DatasetReader(base).episodes["content_hash"])


def test_append_continues_the_recorded_seeds(tmp_path):
    from surrol_data.collect.script_source import collect_script

    out = tmp_path / "script"
    assert collect_script("NeedleReach", 2, out, seed=None, progress=False).seeds == [0, 1]
    assert collect_script("NeedleReach", 2, out, seed=None, append=True, progress=False).seeds == [2, 3]
    reader = DatasetReader(out)
    assert list(reader.episodes["seed"]) == [0, 1, 2, 3]
    assert reader.episodes["content_hash"].is_unique


def test_train_refuses_an_existing_run_dir(tmp_path):
    from surrol_data.algos.train import claim_run_dir

    run = tmp_path / "run"
    claim_run_dir(run, resume=False, overwrite=False)
    (run / "metrics.jsonl").write_text("{}\n")
    (run / "hydra").mkdir()
    with pytest.raises(FileExistsError, match="resume=true .* overwrite=true"):
        claim_run_dir(run, resume=False, overwrite=False)
    claim_run_dir(run, resume=True, overwrite=False)
    assert (run / "metrics.jsonl").exists()
    claim_run_dir(run, resume=False, overwrite=True)
    assert not (run / "metrics.jsonl").exists() and (run / "hydra").exists()


def test_repair_cli_and_automatic_repair_message(base, tmp_path):
    from typer.testing import CliRunner

    from surrol_data.cli import app

    root = tmp_path / "cli"
    shutil.copytree(base, root)
    meta = sorted((root / "meta" / "episodes").rglob("*.parquet"))[-1]
    meta.write_bytes(meta.read_bytes()[:50])  # as if killed before the footer ...
    corruptions.CLASSES["recording session never ended"](root)  # ... which a kill leaves too
    runner = CliRunner()
    run = runner.invoke(app, ["info", str(root)])
    said = " ".join(run.output.split())
    assert run.exit_code == 0, run.output
    assert "repairing it" in said and "dropped episode 2" in said
    again = runner.invoke(app, ["repair", str(root)])
    assert again.exit_code == 0 and "nothing to repair" in again.output
    assert pq.read_metadata(sorted((root / "meta" / "episodes").rglob("*.parquet"))[0]).num_rows == 2
    damaged = corruptions.damaged_copy(base, "actions x100", tmp_path / "x100")
    refused = runner.invoke(app, ["merge", str(tmp_path / "merged"), str(damaged)])
    said = " ".join(refused.output.split())  # rich wraps long lines
    assert refused.exit_code == 2 and "is damaged" in said and "content_hash" in said
    assert not (tmp_path / "merged").exists()


@pytest.mark.slow
def test_full_validation_fuzz(tmp_path):
    """Every class of the catalogue (camera video included) is detected, with LeRobot's check on."""
    root = corruptions.base_dataset(tmp_path / "base", camera=True)
    assert validate_dataset(root, check_reward=False) == []
    assert len(corruptions.CLASSES) >= 50
    silent, crashed = [], []
    for i, name in enumerate(corruptions.CLASSES):
        damaged = corruptions.damaged_copy(root, name, tmp_path / f"d{i}")
        try:
            if not validate_dataset(damaged, check_reward=False):
                silent.append(name)
        except Exception as e:  # noqa: BLE001
            crashed.append(f"{name}: {e!r}")
    assert (silent, crashed) == ([], [])


@pytest.mark.slow
def test_kill_campaign():
    """A short run of the benchmark: it exits 0 only with nothing lost, everything open, every trace present."""
    run = subprocess.run([sys.executable, "benchmarks/crash_safety.py", "--trials", "3", "--signal-trials", "2",
                          "--no-fuzz"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]

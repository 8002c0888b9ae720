"""The recorder opens a new state-only dataset without lerobot and creates the LeRobot dataset at its first checkpoint.

What that must not change: a SIGKILL before the dataset exists loses no finished episode (the journal holds them,
the sidecar the features), ``repair`` builds the same dataset as an unkilled run, and lerobot loads it. What it
buys is checked by what is imported, not by a timing: no lerobot (nor torch) before the first episode is recorded.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from surrol_data.datasets import journal
from surrol_data.datasets.guard import require_valid
from surrol_data.datasets.lerobot_compat import CREATE_STAGING
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.repair import repair
from surrol_data.datasets.schema import PENDING_DATASET, SIDECAR_PATH, frame_features
from surrol_data.datasets.validate import validate_dataset
from surrol_data.datasets.writer import MAX_UNSAVED
from test_recorder import GOAL, OBS, RECORDER_ARGS, assert_same, make_traj, provenance

REPO_ROOT = Path(__file__).resolve().parents[1]
STEPS = 8

CHILD = textwrap.dedent("""
    import json, sys, time
    sys.path.insert(0, {tests!r})
    from test_recorder import make_traj, provenance, RECORDER_ARGS, OBS, GOAL
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.schema import frame_features

    with DatasetRecorder({root!r}, features=frame_features(OBS, GOAL, 5, 1), command="recorded by the test",
                         **RECORDER_ARGS) as rec:
        for i in range(2):
            rec.record(make_traj(i, {steps}), provenance(i))
        heavy = sorted(m for m in ("lerobot", "torch", "datasets") if m in sys.modules)
        print(json.dumps({{"recorded": 2, "imported": heavy}}), flush=True)
        time.sleep(600)   # killed here: the dataset is due at the 10th episode's checkpoint
""")


def _record_two_then_sigkill(root: Path, tmp_path: Path) -> list[str]:
    """Record 2 episodes in a child process, SIGKILL it; the heavy modules it had imported by then."""
    script = tmp_path / "child.py"
    script.write_text(CHILD.format(tests=str(Path(__file__).parent), root=str(root), steps=STEPS))
    proc = subprocess.Popen([sys.executable, str(script)], cwd=REPO_ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError(f"child ended early (rc={proc.wait()}): {proc.stderr.read()[-2000:]}")
        report = json.loads(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert report["recorded"] == 2
    return report["imported"]


def _unkilled(root: Path) -> Path:
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), command="recorded by the test",
                         **RECORDER_ARGS) as rec:
        for i in range(2):
            rec.record(make_traj(i, STEPS), provenance(i))
    return root


def test_sigkill_before_the_dataset_exists_then_repair_keeps_both_episodes(tmp_path):
    root = tmp_path / "killed"
    imported = _record_two_then_sigkill(root, tmp_path)
    assert imported == [], f"the recorder imported {imported} before its first checkpoint"
    # What the kill left: the journal and the sidecar's features, no LeRobot file at all.
    assert [ep for ep, _ in journal.entries(root)] == [0, 1]
    assert not (root / "meta" / "info.json").exists()
    assert PENDING_DATASET in json.loads((root / SIDECAR_PATH).read_text())

    report = repair(root)
    assert (report.episodes_kept, report.episodes_salvaged, report.dropped) == (2, 2, [])
    assert validate_dataset(root, check_reward=False, check_lerobot=True) == []
    assert PENDING_DATASET not in json.loads((root / SIDECAR_PATH).read_text())
    assert not journal.entries(root)

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/killed", root=root, video_backend="pyav")
    assert ds.num_episodes == 2 and ds.num_frames == 2 * STEPS
    reader = DatasetReader(root)
    for ep in range(2):
        assert_same(reader.trajectory(ep), make_traj(ep, STEPS))

    # The same dataset as a recording that was not killed: frames, provenance, per-episode stats.
    whole = _unkilled(tmp_path / "whole")
    for rel in ("data/chunk-000/file-000.parquet",):
        assert pq.read_table(root / rel).equals(pq.read_table(whole / rel)), rel
    # (recorded_at is the clock's; git_commit says -dirty when the tree was edited between the two recordings)
    killed_eps, whole_eps = (DatasetReader(r).episodes.drop(columns=["recorded_at", "git_commit"]) for r in (root, whole))
    assert killed_eps.equals(whole_eps)
    assert json.loads((root / "meta/stats.json").read_text()) == json.loads((whole / "meta/stats.json").read_text())
    ours, theirs = (json.loads((r / "meta/info.json").read_text()) for r in (root, whole))
    assert ours == theirs


def test_a_command_repairs_it_automatically(tmp_path):
    """What every command runs first (require_valid) finds the killed recording and builds its dataset."""
    root = tmp_path / "killed"
    _record_two_then_sigkill(root, tmp_path)
    # as if the kill had come while the dataset was being created: lerobot's half-written staging folder
    (root / CREATE_STAGING / "meta").mkdir(parents=True)
    (root / CREATE_STAGING / "meta" / "info.json").write_text('{"codebase_ver')
    target = require_valid(root, notify=lambda message: None)
    assert target == root and len(DatasetReader(root)) == 2
    assert not (root / CREATE_STAGING).exists()


def test_append_after_the_kill_continues_after_the_two_episodes(tmp_path):
    root = tmp_path / "killed"
    _record_two_then_sigkill(root, tmp_path)
    with DatasetRecorder(root, append=True, **RECORDER_ARGS) as rec:
        assert rec.record(make_traj(2, STEPS), provenance(2)) == 2
    reader = DatasetReader(root)
    assert list(reader.episodes["seed"]) == [100, 101, 102]
    for ep in range(3):
        assert_same(reader.trajectory(ep), make_traj(ep, STEPS))


def test_a_recording_killed_before_its_first_episode_does_not_block_a_retry(tmp_path):
    root = tmp_path / "empty"
    rec = DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), handle_signals=False, **RECORDER_ARGS)
    rec.open()
    rec._lock.release()   # as a SIGKILL would: the folder, the sidecar, no episode
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), **RECORDER_ARGS) as again:
        again.record(make_traj(0, STEPS), provenance(0))
    assert len(DatasetReader(root)) == 1


def test_the_episode_index_and_count_before_the_dataset_exists(tmp_path):
    with DatasetRecorder(tmp_path / "ds", features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=3,
                         **RECORDER_ARGS) as rec:
        assert [rec.record(make_traj(i, STEPS), provenance(i)) for i in range(2)] == [0, 1]
        assert (rec.num_episodes, rec.durable_episodes) == (2, 0)
        assert rec.record(make_traj(2, STEPS), provenance(2)) == 2   # the checkpoint creates the dataset
        assert (rec.num_episodes, rec.durable_episodes) == (3, 3)
        assert rec.record(make_traj(3, STEPS), provenance(3)) == 3
    assert len(DatasetReader(tmp_path / "ds")) == 4


def test_collect_imports_no_lerobot_before_its_first_episode(tmp_path):
    """The real `surrol-data collect` (script source, NeedlePick): what is imported when the first record returns."""
    code = textwrap.dedent(f"""
        import json, sys
        from surrol_data.cli import app
        from surrol_data.datasets.writer import DatasetWriter
        record, seen = DatasetWriter.record, []

        def first_record(self, traj, provenance):
            index = record(self, traj, provenance)
            seen.append(sorted(m for m in ("lerobot", "torch", "datasets", "torchvision") if m in sys.modules))
            return index

        DatasetWriter.record = first_record
        app(["collect", "--source", "script", "--task", "NeedlePick", "--num-episodes", "1",
             "--out", {str(tmp_path / "ds")!r}], standalone_mode=False)
        print(json.dumps({{"at_first_episode": seen[0], "at_exit": "lerobot" in sys.modules}}))
    """)
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True,
                            timeout=600, env={**__import__("os").environ, "HF_HUB_OFFLINE": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    found = json.loads(result.stdout.strip().splitlines()[-1])
    assert found == {"at_first_episode": [], "at_exit": True}, found
    assert len(DatasetReader(tmp_path / "ds")) == 1


@pytest.mark.parametrize("every", [1, 2])
def test_checkpoints_from_the_first_episode_on(tmp_path, every):
    """checkpoint_every 1 creates the dataset at the first record; 2 after one episode held in memory."""
    root = tmp_path / f"every{every}"
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=every,
                         checkpoint_interval_s=None, **RECORDER_ARGS) as rec:
        for i in range(3):
            rec.record(make_traj(i, STEPS), provenance(i))
    reader = DatasetReader(root)
    assert len(reader) == 3
    for ep in range(3):
        assert_same(reader.trajectory(ep), make_traj(ep, STEPS))


def test_a_lazy_open_holds_at_most_max_unsaved_episodes_in_memory(tmp_path):
    """With checkpoints far apart, the dataset is still created after MAX_UNSAVED episodes (memory stays bounded)."""
    root = tmp_path / "ds"
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=1000,
                         checkpoint_interval_s=None, **RECORDER_ARGS) as rec:
        for i in range(MAX_UNSAVED - 1):
            rec.record(make_traj(i, STEPS), provenance(i))
        assert not (root / "meta" / "info.json").exists()
        rec.record(make_traj(MAX_UNSAVED - 1, STEPS), provenance(MAX_UNSAVED - 1))
        assert (root / "meta" / "info.json").exists() and rec.durable_episodes == 0
        rec.record(make_traj(MAX_UNSAVED, STEPS), provenance(MAX_UNSAVED))
    reader = DatasetReader(root)
    assert len(reader) == MAX_UNSAVED + 1
    for ep in range(MAX_UNSAVED + 1):
        assert_same(reader.trajectory(ep), make_traj(ep, STEPS))


def test_collect_append_after_the_kill_starts_after_its_seeds(tmp_path):
    """`collect --append`'s first seed is read after the repair (the killed folder had no info.json to read it from)."""
    from surrol_data.collect.script_source import first_seed

    root = tmp_path / "killed"
    _record_two_then_sigkill(root, tmp_path)   # episode 0: source script, seed 100
    assert first_seed(root, append=True, seed=None, source="script") == 101


def test_lerobot_imported_in_the_background_while_recording(tmp_path):
    """`collect --workers N` imports lerobot in a thread after the first episode; the episodes recorded meanwhile and
    the dataset the checkpoint creates are the same as without it."""
    root, whole = tmp_path / "background", tmp_path / "whole"
    code = textwrap.dedent(f"""
        import sys, threading
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_recorder import make_traj, provenance, RECORDER_ARGS, OBS, GOAL
        from surrol_data.datasets.recorder import DatasetRecorder
        from surrol_data.datasets.schema import frame_features

        with DatasetRecorder({str(root)!r}, features=frame_features(OBS, GOAL, 5, 1), command="recorded by the test",
                             **RECORDER_ARGS) as rec:
            for i in range(12):
                rec.record(make_traj(i, {STEPS}), provenance(i))
                if i == 0:
                    assert "lerobot" not in sys.modules
                    rec.import_lerobot_in_background()
                    assert any(t.name == "surrol_data-import-lerobot" for t in threading.enumerate())
        print("ok")
    """)
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr[-3000:]
    with DatasetRecorder(whole, features=frame_features(OBS, GOAL, 5, 1), command="recorded by the test",
                         **RECORDER_ARGS) as rec:
        for i in range(12):
            rec.record(make_traj(i, STEPS), provenance(i))
    rels = sorted(p.relative_to(whole).as_posix() for p in (whole / "data").rglob("*.parquet"))
    assert rels == sorted(p.relative_to(root).as_posix() for p in (root / "data").rglob("*.parquet"))
    for rel in rels:   # (the two checkpoints' files, consolidated when the recording finished)
        assert pq.read_table(root / rel).equals(pq.read_table(whole / rel)), rel
    assert len(DatasetReader(root)) == 12


DEFERRING = textwrap.dedent("""
    import json, os, signal, sys
    sys.path.insert(0, {tests!r})
    from test_recorder import make_traj, provenance, RECORDER_ARGS, OBS, GOAL
    from surrol_data.datasets import lerobot_compat
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.schema import frame_features

    lerobot_compat.background_import_running = lambda: True   # lerobot's import "takes" the whole recording
    with DatasetRecorder({root!r}, features=frame_features(OBS, GOAL, 5, 1), command="recorded by the test",
                         **RECORDER_ARGS) as rec:
        for i in range({episodes}):
            rec.record(make_traj(i, {steps}), provenance(i))
        print(json.dumps({{"data": os.path.isdir(os.path.join({root!r}, "data")),
                           "journal": len(os.listdir(os.path.join({root!r}, ".surrol_data_journal")))}}), flush=True)
        if {kill}:
            os.kill(os.getpid(), signal.SIGKILL)
""")


@pytest.mark.parametrize("kill", [False, True], ids=["closed", "sigkilled"])
def test_creation_waits_for_a_background_import_and_changes_no_file(tmp_path, kill):
    """While lerobot is imported in the background (`collect`'s rollout workers go on meanwhile), the dataset is not
    created at the 10th episode's checkpoint, which would wait for the import: episodes stay in the journal (durable)
    and in memory. Created later, with a checkpoint where an eager open made each, the files are those of a recording
    that never waited; a SIGKILL meanwhile loses none of them (repair replays the journal)."""
    root, episodes = tmp_path / "deferred", 23
    script = tmp_path / "child.py"
    script.write_text(DEFERRING.format(tests=str(Path(__file__).parent), root=str(root), steps=STEPS,
                                       episodes=episodes, kill=kill))
    run = subprocess.run([sys.executable, str(script)], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == (-signal.SIGKILL if kill else 0), run.stderr[-3000:]
    assert json.loads(run.stdout.splitlines()[0]) == {"data": False, "journal": episodes}
    if kill:
        assert repair(root).episodes_kept == episodes
    whole = tmp_path / "whole"
    with DatasetRecorder(whole, features=frame_features(OBS, GOAL, 5, 1), command="recorded by the test",
                         **RECORDER_ARGS) as rec:
        for i in range(episodes):
            rec.record(make_traj(i, STEPS), provenance(i))
    rels = sorted(p.relative_to(whole).as_posix() for p in whole.rglob("*.parquet"))
    assert rels == sorted(p.relative_to(root).as_posix() for p in root.rglob("*.parquet"))
    clock = ["provenance/recorded_at", "provenance/duration_s", "seal/provenance"]   # when, not what
    for rel in rels:
        if kill and rel.startswith("meta/episodes"):
            continue   # repair writes the replayed episodes' rows itself (checked below through the reader)
        ours, theirs = (pq.ParquetFile(r / rel) for r in (root, whole))
        assert ours.metadata.num_row_groups == theirs.metadata.num_row_groups, rel
        assert ours.read().drop_columns([c for c in clock if c in ours.schema_arrow.names]).equals(
            theirs.read().drop_columns([c for c in clock if c in theirs.schema_arrow.names])), rel
    deferred, eager = (DatasetReader(r).episodes.drop(columns=["recorded_at", "git_commit", "duration_s"])
                       for r in (root, whole))
    assert deferred.equals(eager)
    assert not journal.entries(root)

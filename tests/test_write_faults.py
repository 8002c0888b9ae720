"""Every file-system call of a recording failed on purpose (surrol_data.datasets.fault_injection): whatever call fails
with a full disk, an I/O error or a read-only disk, every episode whose ``record`` returned is in the dataset exactly
once after the repair every command runs first, and the dataset opens. The default run fails a representative
subset of the recorder's sites; the slow test every site with every error; ``benchmarks/crash_safety.py --faults``
does it for every writing command, CLI included (see docs/datasets.md)."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import pytest

from surrol_data.collect.corruptions import GOAL, OBS, _trajectory
from surrol_data.datasets.fault_injection import FaultInjector, distinct_sites
from surrol_data.datasets.guard import ensure_finished
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.schema import frame_features
from surrol_data.datasets.writer import _holds_no_episode

EPISODES = 5


def _record(root: Path, finished: list[str]) -> None:
    """5 episodes, a checkpoint every 2 (so files are closed, the journal emptied, and the session ends by
    consolidating three files), each finished one's content hash appended to ``finished``."""
    from surrol_data.datasets.schema import content_hash

    features = frame_features(OBS, GOAL, 5, 1)
    with DatasetRecorder(root, features=features, task="NeedleReach", env_id="SurRoL/NeedleReach-v0",
                         task_description="reach the needle", checkpoint_every=2, handle_signals=False,
                         lazy=False) as rec:
        for i in range(EPISODES):
            traj = _trajectory(i, 6 + i, False)
            rec.record(traj, {"source": "haptic", "device": "touch", "skill": "expert", "seed": i,
                              "operator_id": "e1"})
            finished.append(content_hash(rec._frame_arrays(traj), rec.features))


@pytest.fixture(scope="module")
def sites(tmp_path_factory) -> dict[str, int]:
    root = tmp_path_factory.mktemp("count") / "ds"
    with FaultInjector() as counting:
        _record(root, [])
    return distinct_sites(counting.sites)


def _trial(tmp_path: Path, call: int, error: str) -> str | None:
    """Fail call ``call`` with ``error``; None when nothing finished was lost or doubled, else what went wrong."""
    root = tmp_path / f"ds_{error}_{call}"
    finished: list[str] = []
    injector = FaultInjector(fail_at=call, error=error)
    with contextlib.suppress(OSError, RuntimeError, ValueError), injector:   # what record / close raise
        _record(root, finished)
    if injector.failed is None:
        return f"call {call} was never made"
    if not root.exists() or _holds_no_episode(root):
        return None if not finished else f"{injector.failed}: {len(finished)} finished, no dataset left"
    ensure_finished(root, lambda message: None)
    present = [str(h) for h in DatasetReader(root).episodes["content_hash"]]
    lost = [h for h in finished if h not in present]
    doubled = [h for h in set(present) if present.count(h) > 1]
    shutil.rmtree(root)
    return None if not lost and not doubled else f"{injector.failed} {error}: lost {lost}, doubled {doubled}"


def test_the_counting_run_sees_every_kind_of_write(sites):
    kinds = {label.split()[0] for label in sites}
    assert {"open", "write", "rename", "mkdir", "unlink", "fsync", "parquet-open", "parquet-write",
            "parquet-close"} <= kinds, kinds
    assert any("journal.py" in s for s in sites) and any("consolidate.py" in s for s in sites)


# a representative subset for the default run: one site in each of the journal, lerobot's data and metadata writers,
# info.json's totals, the recorder's sidecar and the consolidation, with a full disk; and a read-only disk once
_REPRESENTATIVE = ("journal.py", "dataset_writer.py", "dataset_metadata.py", "lerobot_compat.py",
                   "writer.py", "consolidate.py")


def _one_site_per_file(sites: dict[str, int], kinds: tuple[str, ...] | None = None) -> list[int]:
    chosen: dict[str, int] = {}
    for label, call in sites.items():
        kind, where = label.split()[0], label.split()[1].split(":")[0].rsplit("/", 1)[-1]
        if where in _REPRESENTATIVE and (kinds is None or kind in kinds):
            chosen.setdefault(where, call)
    return sorted(chosen.values())


def test_a_full_disk_at_a_representative_site_loses_and_doubles_nothing(sites, tmp_path):
    calls = _one_site_per_file(sites, ("rename", "parquet-close", "write"))
    assert len(calls) >= 5
    assert [why for call in calls if (why := _trial(tmp_path, call, "ENOSPC"))] == []


def test_a_read_only_disk_midway_loses_and_doubles_nothing(sites, tmp_path):
    calls = _one_site_per_file(sites, ("parquet-close",))
    assert calls
    assert [why for call in calls[:1] if (why := _trial(tmp_path, call, "EROFS"))] == []


@pytest.mark.slow
@pytest.mark.parametrize("error", ["ENOSPC", "EIO", "EROFS"])
def test_every_write_site_failed_loses_and_doubles_nothing(sites, tmp_path, error):
    failures = [why for call in sorted(sites.values()) if (why := _trial(tmp_path, call, error))]
    assert failures == [], f"{len(failures)} of {len(sites)} sites: {failures[:5]}"

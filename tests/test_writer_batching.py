"""The recorder writes meta/episodes rows, info.json and stats.json once per checkpoint, not once per episode:
meta/episodes stays small (one parquet row group per checkpoint), and the result is still what lerobot and our
validator read, with the crash guarantee kept by the journal."""

from __future__ import annotations

import json

import pyarrow.parquet as pq

from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.schema import frame_features
from surrol_data.datasets.validate import validate_dataset
from test_recorder import GOAL, OBS, RECORDER_ARGS, make_traj, provenance


def test_episode_rows_are_written_a_checkpoint_at_a_time(tmp_path):
    root = tmp_path / "ds"
    # consolidate=False: the files the checkpoints write (a finished recording merges them, test_consolidate.py)
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=5,
                         checkpoint_interval_s=None, consolidate=False, **RECORDER_ARGS) as rec:
        for i in range(12):
            rec.record(make_traj(i, 8), provenance(i))
            if i == 6:   # between checkpoints: the two durable so far are in info.json, the rest in the journal
                assert json.loads((root / "meta" / "info.json").read_text())["total_episodes"] == 5
                assert len(list((root / ".surrol_data_journal").glob("episode_*.npz"))) == 2
    files = sorted((root / "meta" / "episodes").rglob("*.parquet"))
    groups = [pq.ParquetFile(p).metadata.row_group(g).num_rows for p in files
              for g in range(pq.ParquetFile(p).metadata.num_row_groups)]
    assert sorted(groups) == [2, 5, 5], groups   # one row group per checkpoint (today: one per episode)
    size = sum(p.stat().st_size for p in files)
    assert size / 12 < 40_000, f"{size / 12:.0f} bytes of meta/episodes per episode"   # one footer per checkpoint
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 12 and info["total_frames"] == 12 * 8
    assert validate_dataset(root, check_reward=False) == []   # stats.json and lerobot's own load agree


def test_episode_tables_are_built_without_datasets_from_dict(tmp_path, monkeypatch):
    """lerobot's save_episode built each episode's table through datasets.Dataset.from_dict, whose fingerprint (a dill
    hash of the episode) cost more than the rest of the write. The recorder builds it with pyarrow once from_dict's
    table for the same features has been seen equal, and the data files hold exactly what from_dict gives."""
    import datasets
    from lerobot.datasets import dataset_writer

    from surrol_data.datasets.reader import DatasetReader

    calls = []
    real = datasets.Dataset.from_dict.__func__

    def counting(cls, *args, **kwargs):
        calls.append(1)
        return real(cls, *args, **kwargs)

    monkeypatch.setattr(datasets.Dataset, "from_dict", classmethod(counting))
    features = frame_features(OBS, GOAL, 5, 1)
    trajs = [make_traj(i, 7 + i) for i in range(4)]
    with DatasetRecorder(tmp_path / "fast", features=features, checkpoint_every=10, **RECORDER_ARGS) as rec:
        for i, t in enumerate(trajs):
            rec.record(t, provenance(i))
    # at most the first episode of a feature set in this process (earlier tests may have verified it already)
    assert len(calls) <= 1, f"datasets.Dataset.from_dict ran for {len(calls)} of 4 episodes"
    verified = [s for s in dataset_writer.datasets._verified.values() if s is not None]
    assert verified, "the direct table never matched from_dict's: every episode fell back to it"
    stats_checks = dataset_writer.compute_episode_stats.verified
    assert stats_checks and all(stats_checks.values()), \
        "the fast per-episode stats differed from lerobot's: every episode fell back to compute_episode_stats"

    # The same episodes through lerobot's unpatched path give the same data file.
    from lerobot.datasets import compute_stats

    monkeypatch.setattr(dataset_writer, "datasets", datasets)
    monkeypatch.setattr(dataset_writer, "compute_episode_stats", compute_stats.compute_episode_stats)
    with DatasetRecorder(tmp_path / "slow", features=features, checkpoint_every=10, fast_save=False,
                         **RECORDER_ARGS) as rec:
        for i, t in enumerate(trajs):
            rec.record(t, provenance(i))
    fast = pq.read_table(tmp_path / "fast" / "data" / "chunk-000" / "file-000.parquet")
    slow = pq.read_table(tmp_path / "slow" / "data" / "chunk-000" / "file-000.parquet")
    assert fast.equals(slow, check_metadata=True)
    episodes = "meta/episodes/chunk-000/file-000.parquet"
    stats = [c for c in pq.read_schema(tmp_path / "slow" / episodes).names if c.startswith("stats/")]
    assert stats
    fast_meta = pq.read_table(tmp_path / "fast" / episodes, columns=stats)
    assert fast_meta.equals(pq.read_table(tmp_path / "slow" / episodes, columns=stats))   # quantiles included
    stats_json = [(tmp_path / name / "meta" / "stats.json").read_text() for name in ("fast", "slow")]
    assert stats_json[0] == stats_json[1]
    assert validate_dataset(tmp_path / "fast", check_reward=False) == []
    assert len(DatasetReader(tmp_path / "fast").episodes) == 4

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
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=5,
                         checkpoint_interval_s=None, **RECORDER_ARGS) as rec:
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

"""A dataset that went through lerobot's own tools comes back: its list columns are accepted, and ``surrol-data adopt
EDITED --from ORIGINAL`` restores provenance, seals, device traces, sidecar and card by episode identity. The
card's size category counts frames (a LeRobot dataset's rows)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.collect import corruptions
from surrol_data.datasets.hub_offline import hub_offline, local_repo_id
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.validate import validate_dataset


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """4 haptic episodes (e1, expert) in two data files, with device traces."""
    return corruptions.base_dataset(tmp_path_factory.mktemp("roundtrip") / "base", camera=False)


def _cheap(root: Path) -> list:
    return validate_dataset(root, check_reward=False, check_lerobot=False)


def _adopt(edited: Path, original: Path) -> str:
    run = CliRunner().invoke(app, ["adopt", str(edited), "--from", str(original)])
    assert run.exit_code == 0, run.output
    return " ".join(run.output.split())


def test_lerobot_edit_dataset_delete_episodes_is_adopted_back(base, tmp_path):
    from lerobot.datasets.dataset_tools import delete_episodes
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with hub_offline():
        source = LeRobotDataset(local_repo_id(base), root=base, video_backend="pyav")
        delete_episodes(source, [1], output_dir=tmp_path / "edited", repo_id="local/edited")
    edited = tmp_path / "edited"
    assert "provenance/operator_id" not in pq.read_schema(sorted((edited / "meta/episodes").rglob("*.parquet"))[0]).names
    assert _cheap(edited)  # lerobot's tool dropped provenance, sidecar and traces: refused as it is
    said = _adopt(edited, base)
    assert "adopted 3 episodes" in said and "episodes 0, 2, 3" in said
    assert validate_dataset(edited, check_reward=False) == []  # LeRobotDataset reads it too
    reader, original = DatasetReader(edited), DatasetReader(base)
    for column in ("seed", "operator_id", "skill", "content_hash", "recorded_at"):
        assert list(reader.episodes[column]) == [original.episodes[column][i] for i in (0, 2, 3)]
    for new, old in ((0, 0), (1, 2), (2, 3)):  # traces follow their episodes
        assert (edited / f"meta/device_traces/episode_{new:06d}.npz").read_bytes() == \
            (base / f"meta/device_traces/episode_{old:06d}.npz").read_bytes()
    assert (edited / "README.md").exists()


def test_lerobot_aggregate_datasets_output_is_accepted_then_adopted(base, tmp_path):
    from lerobot.datasets.aggregate import aggregate_datasets

    with hub_offline():
        aggregate_datasets([local_repo_id(base)], "local/agg", roots=[base], aggr_root=tmp_path / "agg")
    agg = tmp_path / "agg"
    said = " ".join(str(p) for p in _cheap(agg))
    assert "values per frame" not in said  # lists of the declared length are the same values
    _adopt(agg, base)
    assert _cheap(agg) == []
    assert list(DatasetReader(agg).episodes["seed"]) == [0, 1, 2, 3]


def test_adopt_refuses_changed_frames(base, tmp_path):
    edited = tmp_path / "edited"
    shutil.copytree(base, edited)
    corruptions.CLASSES["actions x100"](edited)
    before = {p: p.read_bytes() for p in edited.rglob("*") if p.is_file()}
    run = CliRunner().invoke(app, ["adopt", str(edited), "--from", str(base)])
    said = " ".join(run.output.split())
    assert run.exit_code == 2 and "match no episode" in said and "nothing was changed" in said, run.output
    assert {p: p.read_bytes() for p in edited.rglob("*") if p.is_file()} == before


def test_card_size_category_counts_frames(tmp_path):
    from huggingface_hub import DatasetCard

    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.schema import frame_features

    root = tmp_path / "long"
    with DatasetRecorder(root, features=frame_features(corruptions.OBS, corruptions.GOAL, 5, 1), task="NeedleReach",
                         env_id="SurRoL/NeedleReach-v0", task_description="reach", handle_signals=False) as rec:
        rec.record(corruptions._trajectory(0, 1200, False), {"source": "script", "device": "none",
                                                             "skill": "scripted", "seed": 0})
    assert DatasetCard.load(root / "README.md").data.size_categories == ["1K<n<10K"]  # 1 episode, 1200 frames


def test_an_aggregate_of_two_of_our_datasets_is_adopted_from_both(base, tmp_path):
    """lerobot's aggregate_datasets of two of our datasets: `adopt AGG --from A --from B` finds each episode in the
    original that holds its frames."""
    from lerobot.datasets.aggregate import aggregate_datasets

    from surrol_data.datasets.merge import split_dataset

    split_dataset(base, tmp_path / "parts", 0.5, 0, command="test")
    a, b = tmp_path / "parts" / "train", tmp_path / "parts" / "valid"
    with hub_offline():
        aggregate_datasets([local_repo_id(a), local_repo_id(b)], "local/agg2", roots=[a, b], aggr_root=tmp_path / "agg")
    agg = tmp_path / "agg"
    run = CliRunner().invoke(app, ["adopt", str(agg), "--from", str(a), "--from", str(b)])
    said = " ".join(run.output.split())
    assert run.exit_code == 0, run.output
    assert "adopted 4 episodes" in said and "from 2 originals" in said
    assert _cheap(agg) == []
    seeds = list(DatasetReader(a).episodes["seed"]) + list(DatasetReader(b).episodes["seed"])
    assert list(DatasetReader(agg).episodes["seed"]) == seeds and sorted(seeds) == [0, 1, 2, 3]


def test_info_and_validate_of_a_lerobot_edit_point_to_adopt(base, tmp_path):
    """A dataset edited by lerobot-edit-dataset is not damaged (and `repair` has nothing to do): `info` and
    `validate` say to adopt it."""
    from lerobot.datasets.dataset_tools import delete_episodes
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with hub_offline():
        source = LeRobotDataset(local_repo_id(base), root=base, video_backend="pyav")
        delete_episodes(source, [0], output_dir=tmp_path / "edited", repo_id="local/edited")
    edited = tmp_path / "edited"
    for command in (["info", str(edited)], ["validate", str(edited), "--no-lerobot", "--no-reward"]):
        run = CliRunner().invoke(app, command, env={"COLUMNS": "200"})
        said = " ".join(run.output.split())
        assert run.exit_code != 0
        assert f"surrol-data adopt {edited} --from ORIGINAL" in said and "lerobot-edit-dataset" in said, said
        assert "surrol-data repair" not in said
    run = CliRunner().invoke(app, ["repair", str(edited)], env={"COLUMNS": "200"})   # it has nothing to repair
    assert f"surrol-data adopt {edited} --from ORIGINAL" in " ".join(run.output.split())

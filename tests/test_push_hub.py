"""``surrol-data push`` against a local stand-in of the Hub's HTTP API (tests/hub_standin.py; no network): the
dataset of the *second* push is what ``LeRobotDataset(repo_id)`` loads — the ``v3.0`` tag moves to the new
commit, and files of the first push that the second dataset no longer has are deleted, not left to be read."""

from __future__ import annotations

from pathlib import Path

import pytest
from hub_standin import HubStandIn
from typer.testing import CliRunner

from surrol_data.cli import app

from surrol_data.collect.script_source import collect_script
from surrol_data.datasets.merge import filter_dataset
from surrol_data.datasets.reader import DatasetReader

REPO = "lab/needle-reach-demos"


@pytest.fixture
def hub(monkeypatch):
    """The stand-in, and huggingface_hub pointed at it as ``HF_ENDPOINT`` would (that variable is read at import)."""
    from huggingface_hub import constants

    with HubStandIn() as standin:
        monkeypatch.setattr(constants, "ENDPOINT", standin.url)
        monkeypatch.setattr(constants, "HUGGINGFACE_CO_URL_TEMPLATE",
                            standin.url + "/{repo_id}/resolve/{revision}/{filename}")
        monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)  # the test session runs offline otherwise
        monkeypatch.setattr(constants, "HF_HUB_DISABLE_TELEMETRY", True)
        monkeypatch.setenv("HF_TOKEN", "hf_standin")
        yield standin


def _load(repo_id: str, root: Path):
    """What a user elsewhere gets: ``LeRobotDataset(repo_id)`` downloading into an empty folder of its own."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset(repo_id, root=root, video_backend="pyav")
    return {"episodes": ds.num_episodes, "frames": ds.num_frames, "revision": ds.revision,
            "seeds": [int(s) for s in ds.meta.episodes["provenance/seed"]],
            "last_action": ds[len(ds) - 1]["action"].tolist()}


def test_second_push_is_what_lerobot_loads(hub, tmp_path):
    first = tmp_path / "first"
    collect_script("NeedleReach", 2, first, seed=0, max_steps=4, keep_failures=True, progress=False)
    collect_script("NeedleReach", 1, first, seed=None, max_steps=4, keep_failures=True, append=True,
                   progress=False)  # a second session: a second data file and episodes-metadata file
    second = filter_dataset(first, tmp_path / "second", 'seed != 1', progress=False)  # one file each, 2 episodes
    assert len(DatasetReader(first)) == 3 and len(DatasetReader(second)) == 2

    runner = CliRunner()
    pushed = runner.invoke(app, ["push", str(first), "--repo-id", REPO])
    assert pushed.exit_code == 0, pushed.output
    assert _load(REPO, tmp_path / "load_first")["episodes"] == 3
    pushed = runner.invoke(app, ["push", str(second), "--repo-id", REPO])
    assert pushed.exit_code == 0, pushed.output
    seen = _load(REPO, tmp_path / "load_second")

    expected = DatasetReader(second)
    assert seen == {"episodes": 2, "frames": int(expected.episodes["length"].sum()), "revision": "v3.0",
                    "seeds": [int(s) for s in expected.episodes["seed"]],
                    "last_action": expected.trajectory(1).action[-1].tolist()}
    repo = hub.state.repos[REPO]
    assert repo["tags"]["v3.0"] == repo["branches"]["main"]   # the tag names the second push's commit
    files = repo["commits"][repo["branches"]["main"]]
    local = {p.relative_to(second).as_posix() for p in second.rglob("*") if p.is_file()}
    assert set(files) <= local | {".gitattributes"}, sorted(set(files) - local)   # nothing of the first push left
    assert "meta/episodes/chunk-000/file-001.parquet" not in files and "README.md" in files
    assert any(r.startswith("POST /api/datasets/lab/needle-reach-demos/commit/") for r in hub.state.requests)

"""Folder names with ``$HOME``, ``[1]`` and spaces work for every command: lerobot never sees an id it refuses
(it would say "Repo id must use alphanumeric chars" and try the Hub)."""

from __future__ import annotations

import pytest
from huggingface_hub.utils import validate_repo_id
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets.hub_offline import local_repo_id
from surrol_data.datasets.reader import DatasetReader


@pytest.mark.parametrize("name", ["run $HOME [1]", "a[1]", "..", "-x-", "ü b", "x" * 200])
def test_local_repo_ids_are_ones_huggingface_hub_accepts(tmp_path, name):
    validate_repo_id(local_repo_id(tmp_path / name))


def test_collect_append_validate_and_merge_in_odd_folders(tmp_path):
    runner = CliRunner()
    first, second = tmp_path / "demos $HOME [1]", tmp_path / "more demos [2]"
    merged = tmp_path / "all $HOME [3]"

    def ok(*args: str) -> str:
        run = runner.invoke(app, list(args))
        assert run.exit_code == 0, (args, run.output)
        return " ".join(run.output.split())

    collect = ["collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "1", "--max-steps", "15",
               "--keep-failures"]
    ok(*collect, "--out", str(first))
    ok(*collect, "--out", str(first), "--append")
    ok(*collect, "--out", str(second), "--seed", "5")
    assert "is a valid surrol_data dataset" in ok("validate", str(first))  # LeRobotDataset opens it too
    ok("merge", str(first), str(second), "--out", str(merged))
    assert list(DatasetReader(merged).episodes["seed"]) == [0, 1, 5]
    assert "is a valid surrol_data dataset" in ok("validate", str(merged), "--no-reward")

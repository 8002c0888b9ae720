"""Where datasets live and what they claim to be: ``upgrade`` through a symlink and after a killed upgrade, only
LeRobot's "v3.0" format read, and no merged dataset written inside one of its inputs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets.reader import DatasetError, load_info
from surrol_data.datasets.upgrade import schema_version_of

FIXTURES = Path(__file__).resolve().parent / "data" / "schema1"


@pytest.fixture
def camera(tmp_path) -> Path:
    root = tmp_path / "camera"
    shutil.copytree(FIXTURES / "camera", root)
    return root


@pytest.mark.parametrize("version", ["v3.1", "v30", "v3", "v4.0"])
def test_only_the_format_lerobot_0_6_writes_is_read(camera, version):
    info = json.loads((camera / "meta" / "info.json").read_text())
    info["codebase_version"] = version
    (camera / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(DatasetError, match=r"surrol_data reads 'v3\.0'"):
        load_info(camera)


def test_upgrade_through_a_symlink_cleans_a_killed_upgrade_then_merge_refuses_out_inside(camera, tmp_path):
    leftover = tmp_path / ".camera.upgrade-999999"  # what a killed upgrade leaves beside the dataset
    (leftover / "data").mkdir(parents=True)
    (leftover / "data" / "half.parquet").write_bytes(b"PAR1")
    link = tmp_path / "link"
    link.symlink_to(camera, target_is_directory=True)
    run = CliRunner().invoke(app, ["upgrade", str(link)])
    said = " ".join(run.output.split())
    assert run.exit_code == 0 and "Traceback" not in run.output, run.output
    assert "schema 1 → 2" in said and "removed 1 leftover" in said and leftover.name in said
    assert link.is_symlink() and link.resolve() == camera.resolve()
    assert schema_version_of(camera) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camera", "link"]  # no hidden copy, no backup

    inside = camera / "merged"
    run = CliRunner().invoke(app, ["merge", str(camera), "--out", str(inside)])
    said = " ".join(run.output.split())
    assert run.exit_code == 2 and "is inside the input dataset" in said, run.output
    assert not inside.exists()

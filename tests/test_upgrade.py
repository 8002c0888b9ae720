"""`surrol-data upgrade` on datasets written by the schema-1 recorder (tests/data/schema1, made with the code
before schema 2): every value moves, nothing is lost, the result validates, loads in LeRobot and takes new
episodes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets.reader import DatasetError, DatasetReader, column_to_numpy
from surrol_data.datasets.validate import validate_dataset

FIXTURES = Path(__file__).resolve().parent / "data" / "schema1"


def _old_frames(root: Path) -> pa.Table:
    return pa.concat_tables(pq.read_table(p) for p in sorted((root / "data").glob("chunk-*/file-*.parquet")))


def _old_episodes(root: Path) -> pa.Table:
    tables = [pq.read_table(p) for p in sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))]
    return pa.concat_tables(tables).sort_by("episode_index")


def _np(table: pa.Table, name: str) -> np.ndarray:
    return column_to_numpy(table.column(name)).reshape(table.num_rows, -1)


def _upgrade(root: Path, *args: str):
    result = CliRunner().invoke(app, ["upgrade", str(root), *args])
    assert result.exit_code == 0, result.output
    return " ".join(result.output.split())  # rich wraps long lines


@pytest.fixture
def camera(tmp_path) -> Path:
    root = tmp_path / "camera"
    shutil.copytree(FIXTURES / "camera", root)
    return root


def test_schema1_is_refused_with_the_upgrade_command(camera):
    with pytest.raises(DatasetError, match="surrol-data upgrade"):
        DatasetReader(camera).trajectory(0)
    problems = validate_dataset(camera, check_reward=False, check_lerobot=False)
    assert [p.check for p in problems] == ["schema"] and "surrol-data upgrade" in problems[0].message
    from surrol_data.datasets.recorder import DatasetRecorder

    with pytest.raises(DatasetError, match="surrol-data upgrade"):  # appending (collect --append) says the same
        DatasetRecorder(camera, append=True, task="NeedleReach", env_id="SurRoL/NeedleReach-v0",
                        task_description="reach the needle")


def test_upgrade_moves_every_value_and_keeps_videos_traces_and_provenance(camera):
    old_data, old_meta = _old_frames(camera), _old_episodes(camera)
    old_stats = json.loads((camera / "meta" / "stats.json").read_text())
    video = sorted((camera / "videos").rglob("*.mp4"))
    video_bytes = [p.read_bytes() for p in video]
    traces = {p.name: p.read_bytes() for p in (camera / "meta" / "device_traces").iterdir()}

    output = _upgrade(camera, "--keep-backup")
    assert "schema 1 → 2, 4 episodes, 30 frames" in output
    assert (camera.parent / "camera.schema1").is_dir()

    info = json.loads((camera / "meta" / "info.json").read_text())
    f = info["features"]
    assert not any(k.endswith("_goal") for k in f)
    assert f["observation.environment_state"]["names"] == ["tip_x", "tip_y", "tip_z", "goal_x", "goal_y", "goal_z"]
    assert f["observation.state"]["names"] == ["tip_x", "tip_y", "tip_z", "tip_roll", "tip_pitch", "tip_yaw", "jaw"]
    assert f["next.truncated"]["dtype"] == "bool" and info["robot_type"] == "dvrk_psm"
    assert f["observation.images.front"]["info"]["video.codec"]  # the stream's description travels with it

    reader = DatasetReader(camera)
    new = reader.transitions()
    order = np.argsort(column_to_numpy(old_data.column("index")))
    for key, column in (("achieved_goal", "observation.achieved_goal"), ("desired_goal", "observation.desired_goal"),
                        ("next_achieved_goal", "next.observation.achieved_goal"),
                        ("next_desired_goal", "next.observation.desired_goal"), ("obs", "observation.state"),
                        ("action", "action")):
        assert np.array_equal(new[key], _np(old_data, column)[order]), key
    data = pa.concat_tables(pq.read_table(p) for p in sorted((camera / "data").glob("chunk-*/file-*.parquet")))
    truncated = column_to_numpy(data.column("next.truncated")).reshape(-1)
    episodes = column_to_numpy(data.column("episode_index"))
    last = np.append(episodes[1:] != episodes[:-1], True)
    assert np.array_equal(truncated, last)  # none of these episodes terminated: each ends truncated
    assert [pq.ParquetFile(p).num_row_groups for p in sorted((camera / "data").glob("chunk-*/*.parquet"))] == [2, 2]

    meta = _old_episodes(camera)
    for name in old_meta.column_names:
        if name.startswith("provenance/") and name != "provenance/content_hash" or name.startswith("videos/"):
            assert meta.column(name).to_pandas().equals(old_meta.column(name).to_pandas()), name
    assert meta.column("provenance/content_hash").to_pylist() != old_meta.column("provenance/content_hash").to_pylist()
    for stat in ("min", "max", "mean", "std", "q50"):
        got = meta.column(f"stats/observation.environment_state/{stat}").to_pylist()
        want = [a + d for a, d in zip(old_meta.column(f"stats/observation.achieved_goal/{stat}").to_pylist(),
                                      old_meta.column(f"stats/observation.desired_goal/{stat}").to_pylist(), strict=True)]
        assert got == want, stat
    assert meta.column("stats/next.truncated/max").to_pylist() == [[1.0]] * 4
    stats = json.loads((camera / "meta" / "stats.json").read_text())
    assert stats["observation.environment_state"]["mean"] == (old_stats["observation.achieved_goal"]["mean"]
                                                              + old_stats["observation.desired_goal"]["mean"])
    assert stats["next.truncated"]["max"] == [1.0] and "observation.achieved_goal" not in stats

    assert [p.read_bytes() for p in sorted((camera / "videos").rglob("*.mp4"))] == video_bytes
    assert {p.name: p.read_bytes() for p in (camera / "meta" / "device_traces").iterdir()} == traces
    side = json.loads((camera / "meta" / "surrol_data.json").read_text())
    assert side["schema_version"] == 2 and side["upgrades"][-1]["from_schema"] == 1
    assert side["checkpoint"]["info"]["features"] == info["features"]  # what repair would fall back to

    # it validates (LeRobot opens it and decodes the video) and says so when run again
    assert validate_dataset(camera, check_reward=False) == []
    assert "already in schema 2" in _upgrade(camera)


def test_upgraded_needle_pick_validates_against_its_env_and_takes_new_episodes(tmp_path):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path / "needle_pick"
    shutil.copytree(FIXTURES / "needle_pick", root)
    _upgrade(root)
    assert not (tmp_path / "needle_pick.schema1").exists()
    assert validate_dataset(root, check_lerobot=False) == []  # rewards agree with the env's compute_reward
    names = json.loads((root / "meta" / "info.json").read_text())["features"]["observation.state"]["names"]
    assert names[7:10] == ["needle_x", "needle_y", "needle_z"]
    collect_script("NeedlePick", 1, root, append=True, max_steps=5, keep_failures=True, progress=False)
    reader = DatasetReader(root)
    assert len(reader) == 3 and len(reader.trajectory(2)) == 5
    assert validate_dataset(root, check_reward=False) == []


def test_upgrade_seals_every_episode_as_the_writer_does(camera):
    # The writer seals each episode's provenance and video segment; an upgraded dataset must be sealed the same way,
    # so an edit after the upgrade is caught as it is in a freshly recorded one.
    from surrol_data.datasets.info import read_sidecar
    from surrol_data.datasets.schema import PROVENANCE_SEAL

    _upgrade(camera)
    assert read_sidecar(camera).get("seals") == 1
    meta = _old_episodes(camera)
    assert PROVENANCE_SEAL in meta.column_names and "seal/observation.images.front" in meta.column_names
    assert None not in meta.column(PROVENANCE_SEAL).to_pylist()
    assert validate_dataset(camera, check_reward=False, check_lerobot=False) == []

    path = sorted((camera / "meta" / "episodes").glob("chunk-*/file-*.parquet"))[0]
    table = pq.read_table(path)
    skill = table.column("provenance/skill").to_pylist()
    table = table.set_column(table.column_names.index("provenance/skill"), "provenance/skill",
                             pa.array(["novice" if s != "novice" else "expert" for s in skill], pa.string()))
    pq.write_table(table, path)
    problems = validate_dataset(camera, check_reward=False, check_lerobot=False)
    assert any(p.check == "integrity" and "episode" in p.message for p in problems), problems


def test_a_swap_that_fails_halfway_puts_the_original_back(camera, monkeypatch):
    """Where the system cannot swap the two folders in one step, the upgrade renames twice; the second rename failing
    (a full or failing disk) must leave the original under its own name, as it was."""
    import errno
    import os

    import surrol_data.datasets.upgrade as upgrade

    def files():   # (the dataset's lock file stays, as after every command that writes it)
        return sorted(p.relative_to(camera).as_posix() for p in camera.rglob("*") if p.name != ".surrol_data.lock")

    before = files()
    monkeypatch.setattr(upgrade, "_exchange", lambda a, b: False)
    real = os.replace

    def replace(src, dst):
        if Path(src).name.startswith(".camera.upgrade-"):
            raise OSError(errno.EIO, "Input/output error", str(dst))
        return real(src, dst)

    monkeypatch.setattr(upgrade.os, "replace", replace)
    with pytest.raises(OSError):
        upgrade.upgrade_dataset(camera)
    assert files() == before
    assert not list(camera.parent.glob(".camera.upgrade-*")) and not (camera.parent / "camera.schema1").exists()


def test_the_upgraded_copy_is_swapped_in_in_one_step_where_the_system_can(camera):
    import surrol_data.datasets.upgrade as upgrade

    a, b = camera.parent / "a", camera.parent / "b"
    a.mkdir(), b.mkdir()
    (a / "x").write_text("a"), (b / "y").write_text("b")
    if not upgrade._exchange(a, b):
        pytest.skip("this file system cannot exchange two paths in one step (renameat2 RENAME_EXCHANGE)")
    assert (a / "y").read_text() == "b" and (b / "x").read_text() == "a"

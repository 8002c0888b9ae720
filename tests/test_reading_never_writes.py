"""Commands that read a dataset never modify it: a finished dataset damaged on disk (bit rot) is refused with the
repair command to run; only a recording left unfinished (the journal or its last session says so) is repaired
automatically, and one on a read-only mount is read through a repaired view without a write to it."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import sys
from pathlib import Path

import private_mounts
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.collect import corruptions
from surrol_data.datasets.recorder import DatasetRecorder

ARGS = dict(task="NeedleReach", env_id="SurRoL/NeedleReach-v0", task_description="reach the needle")


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return corruptions.base_dataset(tmp_path_factory.mktemp("readonly") / "base", camera=False)


@pytest.fixture(scope="module")
def killed(base, tmp_path_factory) -> Path:
    """The files of a recording killed mid-session (3 episodes in its journal, a footer-less episodes file)."""
    work = tmp_path_factory.mktemp("killed")
    root = work / "live"
    shutil.copytree(base, root)
    rec = DatasetRecorder(root, append=True, checkpoint_every=100, handle_signals=False, **ARGS)
    rec.open()
    for i in range(3):
        rec.record(corruptions._trajectory(10 + i, 5, False),
                   {"source": "script", "device": "none", "skill": "scripted", "seed": 10 + i})
    frozen = work / "killed"
    shutil.copytree(root, frozen)  # the files as they are mid-session
    rec.close()
    (frozen / ".surrol_data.lock").unlink()  # the kernel drops a dead process's lock
    return frozen


def digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_bit_rot_is_refused_by_every_read_command_and_nothing_changes(base, tmp_path):
    root = tmp_path / "rotten"
    shutil.copytree(base, root)
    data = sorted((root / "data").rglob("*.parquet"))[0]
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])  # a finished dataset, cut on disk
    before = digests(root)
    runner = CliRunner()
    for args in (["info", str(root)],
                 ["filter", str(root), "--out", str(tmp_path / "f"), "--where", "success"],
                 ["merge", str(root), "--out", str(tmp_path / "m")],
                 ["export", str(root), "--format", "robomimic", "--out", str(tmp_path / "e.hdf5")]):
        run = runner.invoke(app, args)
        said = " ".join(run.output.split())
        assert run.exit_code == 2 and "Traceback" not in run.output, run.output
        assert said.startswith("error:") and said.count("error:") == 1, (args[0], said)
        assert "data/chunk-000/file-000.parquet" in said and f"surrol-data repair {root}" in said, (args[0], said)
        assert "nothing was changed" in said
    run = runner.invoke(app, ["validate", str(root), "--no-lerobot", "--no-reward"])
    assert run.exit_code == 1 and "data/chunk-000/file-000.parquet" in " ".join(run.output.split())
    assert digests(root) == before
    assert not any((tmp_path / n).exists() for n in ("f", "m", "e.hdf5"))


def test_a_killed_recording_is_still_repaired_automatically(killed, tmp_path):
    root = tmp_path / "k"
    shutil.copytree(killed, root)
    run = CliRunner().invoke(app, ["info", str(root)])
    said = " ".join(run.output.split())
    assert run.exit_code == 0 and "killed recording" in said and "repairing it" in said, said
    assert re.search(r"episodes\s*│\s*7\b", run.output), run.output


_IN_MOUNT = """
import json, sys
from typer.testing import CliRunner
from surrol_data.cli import app
root, out = sys.argv[1], sys.argv[2]
runner = CliRunner()
results = {}
for name, args in {"info": ["info", root],
                   "filter": ["filter", root, "--out", out + "/f", "--where", "seed >= 10"],
                   "merge": ["merge", root, "--out", out + "/m"],
                   "export": ["export", root, "--format", "robomimic", "--out", out + "/e.hdf5"]}.items():
    run = runner.invoke(app, args)
    results[name] = {"code": run.exit_code, "output": run.output,
                     "exception": None if run.exception is None or isinstance(run.exception, SystemExit)
                     else repr(run.exception)}
print("RESULTS " + json.dumps(results))
"""


def test_a_killed_dataset_on_a_read_only_mount_can_be_read(killed, tmp_path):
    why = private_mounts.skip_reason()
    if why:
        pytest.skip(why)
    root = tmp_path / "ro"
    shutil.copytree(killed, root)
    out = tmp_path / "out"
    out.mkdir()
    before = digests(root)
    script = tmp_path / "in_mount.py"
    script.write_text(_IN_MOUNT)
    shell = (f"mount --bind '{root}' '{root}' && mount -o remount,bind,ro '{root}' && "
             f"! touch '{root}/probe' 2>/dev/null && '{sys.executable}' '{script}' '{root}' '{out}'")
    run = private_mounts.run(shell, timeout=900)
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULTS ")]
    assert run.returncode == 0 and lines, run.stdout[-3000:] + run.stderr[-3000:]
    results = json.loads(lines[0].removeprefix("RESULTS "))
    for name, r in results.items():
        assert r["code"] == 0 and r["exception"] is None, (name, r)
    info = " ".join(results["info"]["output"].split())
    assert "cannot be written here" in info and re.search(r"episodes\s*│\s*7\b", results["info"]["output"]), info
    assert digests(root) == before  # nothing written, not even the lock
    from surrol_data.datasets.reader import DatasetReader

    assert list(DatasetReader(out / "f").episodes["seed"]) == [10, 11, 12]
    assert len(DatasetReader(out / "m")) == 7
    assert (out / "e.hdf5").exists()

"""A full disk is a one-line error with nothing lost: ``collect`` into a small tmpfs stops with one line, ``info`` and
``repair`` on the full disk say one line (or succeed), and once there is space again every episode recorded before
the disk filled is in the repaired dataset. Runs in a private mount namespace (``unshare --mount``, root)."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

import private_mounts

_COMMANDS = """
import json, sys
from pathlib import Path
from typer.testing import CliRunner
from surrol_data.cli import app
from surrol_data.datasets import journal
root, phase = Path(sys.argv[1]), sys.argv[2]
runner = CliRunner()

def run(*args):
    r = runner.invoke(app, list(args))
    return {"code": r.exit_code, "output": r.output,
            "exception": None if r.exception is None or isinstance(r.exception, SystemExit) else repr(r.exception)}

# (collect rolls out in a spawned process, which imports this script again: the guard)
if __name__ == "__main__":
    results = {}
    if phase == "full":
        results["collect"] = run("collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "500",
                                 "--max-steps", "15", "--keep-failures", "--out", str(root))
        side = json.loads((root / "meta" / "surrol_data.json").read_text())
        durable = int(side.get("checkpoint", {}).get("episodes", 0))   # none: the dataset was still to be created
        results["recorded"] = durable + len([i for i, _ in journal.entries(root) if i >= durable])
        results["info"] = run("info", str(root))
        results["repair"] = run("repair", str(root))
    else:
        results["repair"] = run("repair", str(root))
        results["validate"] = run("validate", str(root), "--no-lerobot", "--no-reward")
        from surrol_data.datasets.reader import DatasetReader
        results["episodes"] = len(DatasetReader(root))
        results["seeds"] = [int(x) for x in DatasetReader(root).episodes["seed"]]
    print("RESULTS " + json.dumps(results))
"""


def _one_line_error(result: dict) -> bool:
    said = " ".join(result["output"].split())
    return (result["exception"] is None and "Traceback" not in result["output"]
            and (result["code"] == 0 or (result["code"] == 2 and said.count("error:") == 1)))


def _on_a_tmpfs(tmp_path, source: str, size: str, then, timeout: float):
    """Mount a tmpfs of ``size`` at ``tmp_path/disk`` (in a private mount namespace; the test skips where mounts cannot
    be made), then run the shell line ``then(disk, python)`` (``python``: the script ``source``, quoted); (the run, the
    JSON of each line the script printed after "RESULTS ")."""
    why = private_mounts.skip_reason()
    if why:
        pytest.skip(why)
    disk = tmp_path / "disk"
    disk.mkdir()
    script = tmp_path / "script.py"
    script.write_text(source)
    run = private_mounts.run(f"mount -t tmpfs -o size={size} tmpfs '{disk}' && "
                             + then(disk, f"'{sys.executable}' '{script}'"), timeout=timeout)
    return run, [json.loads(line.removeprefix("RESULTS ")) for line in run.stdout.splitlines()
                 if line.startswith("RESULTS ")]


def test_disk_full_is_one_line_and_loses_nothing(tmp_path):
    run, lines = _on_a_tmpfs(tmp_path, _COMMANDS, "1m", lambda disk, py: (
        f"{py} '{disk / 'demos'}' full && mount -o remount,size=256m '{disk}' && {py} '{disk / 'demos'}' space"),
        timeout=1200)
    assert run.returncode == 0 and len(lines) == 2, run.stdout[-3000:] + run.stderr[-3000:]
    full, space = lines
    collect = " ".join(full["collect"]["output"].split())
    assert full["collect"]["code"] == 2 and "no space left on the disk" in collect, collect
    assert f"every episode finished is kept: {full['recorded']} in" in collect, collect
    assert _one_line_error(full["collect"]) and full["recorded"] >= 1, full
    for name in ("info", "repair"):
        assert _one_line_error(full[name]), (name, full[name])
    assert space["repair"]["code"] == 0 and space["validate"]["code"] == 0, space
    assert space["episodes"] == full["recorded"]  # every episode recorded before the disk filled
    assert space["seeds"] == list(range(full["recorded"]))   # each once (a stopped close had dropped some, doubled others)


_EXPORT = """
import json, sys
from pathlib import Path
from typer.testing import CliRunner
from surrol_data.cli import app
from surrol_data.collect import corruptions
base, out = Path(sys.argv[1]), Path(sys.argv[2])
corruptions.base_dataset(base, camera=False)
r = CliRunner().invoke(app, ["export", str(base), "--format", "robomimic", "--out", str(out)])
print("RESULTS " + json.dumps({"code": r.exit_code, "output": r.output, "exception": None if r.exception is None
                               or isinstance(r.exception, SystemExit) else repr(r.exception),
                               "left": sorted(p.name for p in out.parent.iterdir())}))
"""


def test_an_export_onto_a_full_disk_is_one_line_and_leaves_no_file(tmp_path):
    """h5py writing its file itself met the full tmpfs with a screen of 'Exception ignored' tracebacks, then a
    segmentation fault, and left OUT.partial behind."""
    run, lines = _on_a_tmpfs(tmp_path, _EXPORT, "16k", lambda disk, py: f"{py} '{tmp_path / 'base'}' "
                                                                       f"'{disk / 'demos.hdf5'}'", timeout=600)
    assert run.returncode == 0 and len(lines) == 1, (run.returncode, run.stdout[-2000:] + run.stderr[-3000:])
    said = " ".join(lines[0]["output"].split())
    assert _one_line_error(lines[0]) and lines[0]["code"] == 2 and "no space left on the disk" in said, lines[0]
    assert "Traceback" not in run.stderr and "nothing was written to" in said, run.stderr[-2000:]
    assert lines[0]["left"] == [], lines[0]   # no half-written file


def _tmpfs_campaign(paths: list[str], timeout: float) -> subprocess.CompletedProcess:
    """``benchmarks/crash_safety.py --tmpfs``: each path run on a real tmpfs with room for half of what it writes,
    the tmpfs then enlarged; it exits 0 only when every path filled its tmpfs, nothing finished was lost or
    duplicated, each error was one line naming what is kept, no traceback, and every output opens."""
    return subprocess.run([sys.executable, "benchmarks/crash_safety.py", "--tmpfs", *(["--tmpfs-paths", *paths] if paths
                                                                                    else [])],
                          cwd=private_mounts.REPO_ROOT, capture_output=True, text=True, timeout=timeout)


# the fast representative: a path that needs no base recording (the schema-1 fixture is its input), whose output is
# built beside its input and swapped in; `collect` is the reproduction above
def test_a_real_tmpfs_filled_during_an_upgrade_loses_nothing():
    why = private_mounts.skip_reason()
    if why:
        pytest.skip(why)
    run = _tmpfs_campaign(["upgrade"], timeout=600)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "1 paths on a real tmpfs, 1 filled it" in " ".join(run.stdout.split()), run.stdout[-2000:]


@pytest.mark.slow
def test_a_real_tmpfs_filled_during_every_writing_path_loses_nothing():
    why = private_mounts.skip_reason()
    if why:
        pytest.skip(why)
    run = _tmpfs_campaign([], timeout=3600)   # every writing path of the fault sweep
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    said = " ".join(run.stdout.split())
    counts = re.search(r"(\d+) paths on a real tmpfs, (\d+) filled it", said)
    assert counts and counts[1] == counts[2] and int(counts[1]) >= 14, said[-2000:]

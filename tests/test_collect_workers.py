"""`collect --workers N`: episodes rolled out in N processes, recorded in seed order — the same dataset as one, and
as rolling out in the recording process itself (``workers=0``)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.collect.script_source import collect_script
from surrol_data.datasets.journal import journal_dir
from surrol_data.datasets.reader import DatasetReader

REPO_ROOT = Path(__file__).resolve().parents[1]


def _provenance(root):
    episodes = DatasetReader(root).episodes.drop(columns=["duration_s", "command"], errors="ignore")
    return episodes[[c for c in episodes.columns if not c.startswith(("seal/", "provenance_seal"))]]


@pytest.mark.parametrize("workers", [1, 2])
def test_worker_processes_record_the_same_episodes_as_the_recording_process(tmp_path, workers):
    # a short horizon: short episodes, some of them failures (kept), from seeds 0..3 in every process
    here = collect_script("NeedleReach", 4, tmp_path / "here", max_steps=12, keep_failures=True, progress=False,
                          workers=0)
    there = collect_script("NeedleReach", 4, tmp_path / "there", max_steps=12, keep_failures=True, progress=False,
                           workers=workers)
    assert there.seeds == here.seeds and there.attempts == here.attempts
    a, b = DatasetReader(tmp_path / "here"), DatasetReader(tmp_path / "there")
    for ep in range(4):
        ta, tb = a.trajectory(ep), b.trajectory(ep)
        for name in ("observation", "action", "reward", "success", "tip_position", "jaw_angle"):
            np.testing.assert_array_equal(getattr(ta, name), getattr(tb, name), err_msg=f"episode {ep} {name}")
    pa_, pb = _provenance(tmp_path / "here"), _provenance(tmp_path / "there")
    assert list(pa_["content_hash"]) == list(pb["content_hash"])
    assert list(pa_["seed"]) == list(pb["seed"]) == here.seeds


def test_workers_need_the_script_source(tmp_path):
    result = CliRunner().invoke(app, ["collect", "--source", "haptic", "--device", "operator", "--task",
                                      "NeedleReach", "--num-episodes", "1", "--out", str(tmp_path / "x"),
                                      "--workers", "2"])
    assert result.exit_code == 2 and "--workers" in result.output and "Traceback" not in result.output


def _collect_until_two_episodes_are_durable(out: Path, *more: str) -> subprocess.Popen:
    """``collect`` (``more``: further options) started in its own process group, once two episodes are durable (in a
    journal: the dataset's, or a shard's beside it)."""
    proc = subprocess.Popen([sys.executable, "-m", "surrol_data.cli", "collect", "--source", "script", "--task",
                             "NeedleReach", "--num-episodes", "10000", "--out", str(out), *more],
                            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 300
    while len(list(out.parent.rglob(f"{journal_dir('').name}/episode_*.npz"))) < 2:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1][-3000:]
        time.sleep(0.1)
    return proc


def _alive_in_group(pgid: int) -> list[str]:
    group = subprocess.run(["ps", "-o", "stat=,args=", "-g", str(pgid)], capture_output=True, text=True).stdout
    return [line for line in group.splitlines() if not line.lstrip().startswith("Z")]   # zombies have exited


def test_ctrl_c_keeps_the_finished_episodes_and_says_so(tmp_path):
    """Ctrl-C reaches the whole process group (the recorder and its rollout worker): the command ends with what the
    dataset holds and how to go on, no traceback; every episode finished before it is readable; no worker is left."""
    out = tmp_path / "stopped"
    proc = _collect_until_two_episodes_are_durable(out)
    os.killpg(proc.pid, signal.SIGINT)   # what a terminal does on Ctrl-C
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err
    held = int(re.search(r"holds (\d+) episodes", err).group(1))
    assert held >= 2 and len(DatasetReader(out)) == held
    assert "--append" in err
    assert not _alive_in_group(proc.pid)   # the rollout worker is gone too


@pytest.mark.parametrize("parallel", [[], ["--shards", "2"]], ids=["worker", "shards"])
def test_a_killed_recorder_leaves_no_worker_behind(tmp_path, parallel):
    """SIGKILL (or the OOM killer) ends the command's process alone: its rollout worker (idle on its task queue) or
    its shard processes must not live on, each holding a simulator."""
    proc = _collect_until_two_episodes_are_durable(tmp_path / "killed", *parallel)
    proc.kill()
    proc.communicate(timeout=60)
    deadline = time.monotonic() + 30
    while _alive_in_group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive_in_group(proc.pid)

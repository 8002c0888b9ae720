"""Issue 28: `surrol-data train` shows per-epoch progress, ends by saying where its outputs are, and a Ctrl-C
ends with one line naming the command that resumes the run (not a traceback)."""

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "surrol_data.cli"]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _overrides(*extra):
    return ["task=NeedleReach", "algo=ddpg", "demos=none", "experiment=smoke", "run_dir=run", "tensorboard=false",
            *extra]


def test_a_finished_run_says_where_its_outputs_are(tmp_path):
    done = subprocess.run([*CLI, "train", *_overrides("experiment.epochs=1")], cwd=tmp_path, env=ENV,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    said = done.stdout.splitlines()
    assert said[0].startswith("trained SurRoL/NeedleReach-v0 for 1 epoch(s): final success ")
    for label, path in (("run folder", "run"), ("policy", "run/policy.pt"), ("metrics", "run/metrics.csv")):
        assert any(line.split() == [*label.split(), path] for line in said), said
        assert (tmp_path / path).exists()
    assert "train NeedleReach-v0" in done.stderr and "1/1" in done.stderr   # the per-epoch progress bar


def test_ctrl_c_ends_with_the_command_that_resumes(tmp_path):
    overrides = _overrides("experiment.epochs=12")
    run = subprocess.Popen([*CLI, "train", *overrides], cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, start_new_session=True)
    metrics = tmp_path / "run" / "metrics.jsonl"
    deadline = time.time() + 180
    while time.time() < deadline and run.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 2:   # epochs 0 and 1 are done
            break
        time.sleep(0.05)
    assert run.poll() is None, "the run ended before it could be interrupted"
    os.killpg(run.pid, signal.SIGINT)   # what Ctrl-C in a terminal does: the whole foreground group
    _, err = run.communicate(timeout=120)
    assert run.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted; ") and "Resume with: " in last
    command = shlex.split(last.split("Resume with: ", 1)[1])
    assert command == ["surrol-data", "train", *overrides, "resume=true"]
    resumed = subprocess.run([*CLI, *command[1:]], cwd=tmp_path, env=ENV, capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    assert [r["epoch"] for r in rows] == list(range(13))


def test_the_resume_command_keeps_the_overrides_and_replaces_resume_and_overwrite():
    from surrol_data.train_app import resume_command

    assert resume_command(["-m", "seed=0,1", "run_dir=my runs/x", "resume=false", "overwrite=true"]) == \
        "surrol-data train -m seed=0,1 'run_dir=my runs/x' resume=true"


def test_a_sweep_job_that_left_no_result_is_a_failed_row(tmp_path, capsys):
    """A job killed by the OS or the scheduler (out of memory, out of time, cancelled) writes no line: the sweep's
    table still lists it, as failed, and counts it."""
    from surrol_data.train_app import _cluster_launcher, _expected_jobs, _print_sweep_report

    args = ["-m", "hydra/launcher=slurm", "hydra.launcher.partition=cpu", "seed=0,1", "task=NeedleReach"]
    expected = _expected_jobs(args)
    assert expected == ["seed=0 task=NeedleReach", "seed=1 task=NeedleReach"] and _cluster_launcher(args)
    assert not _cluster_launcher(["-m", "seed=0,1"]) and _expected_jobs(["seed=0"]) == []
    report = tmp_path / "jobs.jsonl"
    report.write_text(json.dumps({"num": 1, "job": expected[1], "status": "ok", "detail": "final success 1.00",
                                  "run_dir": "runs/x/seed1"}) + "\n")
    assert _print_sweep_report(report, expected, cluster=True) == 1
    table = " ".join(capsys.readouterr().err.split())
    assert "sweep: 2 job(s)" in table and "killed or never ran" in table and ".submitit" in table
    assert table.index("seed=0") < table.index("seed=1")          # in job order

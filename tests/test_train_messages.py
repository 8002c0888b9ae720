"""Issue 28: `surrol-data train` shows per-epoch progress, ends by saying where its outputs are, and a Ctrl-C
ends with one line naming the command that resumes the run (not a traceback)."""

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "surrol_data.cli"]
# as from a shell with the environment active (not under `uv run`): the resume hint is plain `surrol-data ...`
ENV = {**{k: v for k, v in os.environ.items() if k != "UV"}, "PYTHONPATH": str(REPO),
       "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}


def _overrides(*extra):
    return ["task=NeedleReach", "algo=ddpg", "demos=none", "experiment=smoke", "run_dir=run", "tensorboard=false",
            *extra]


def test_a_finished_run_says_where_its_outputs_are(tmp_path):
    done = subprocess.run([*CLI, "train", *_overrides("experiment.epochs=2")], cwd=tmp_path, env=ENV,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    said = done.stdout.splitlines()
    assert said[0].startswith("trained SurRoL/NeedleReach-v0 for 2 epoch(s): final success ")
    # what to expect, before the first epoch and measured after it
    err = " ".join(done.stderr.split())
    assert "2 epoch(s) to go, each 4 episodes (200 env steps" in err and "an epoch on a 2-core CPU" in err
    assert "Success often stays at 0 for the first epochs" in err
    assert re.search(r"epoch 1 took \d+ s \(collect \d+ s, updates \d+ s, evaluation \d+ s\): the 1 left take about "
                     r"\d+ s", err), err
    for label, path in (("run folder", "run"), ("policy", "run/policy.pt"), ("metrics", "run/metrics.csv")):
        assert any(line.split() == [*label.split(), path] for line in said), said
        assert (tmp_path / path).exists()
    assert "train NeedleReach-v0" in done.stderr and "2/2" in done.stderr   # the per-epoch progress bar


def _interrupted_run(folder, overrides):
    """A run sent Ctrl-C once its epochs 0 and 1 are done: (the process, its stderr, its metrics file)."""
    # A terminal's foreground job has Ctrl-C's default action; the tests may run in a background job, whose
    # processes inherit SIGINT ignored (a non-interactive shell's `&`), and an ignored SIGINT is left alone by train.
    run = subprocess.Popen([*CLI, "train", *overrides], cwd=folder, env=ENV, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, start_new_session=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    metrics = folder / "run" / "metrics.jsonl"
    deadline = time.time() + 180
    while time.time() < deadline and run.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 2:   # epochs 0 and 1 are done
            break
        time.sleep(0.05)
    assert run.poll() is None, "the run ended before it could be interrupted"
    os.killpg(run.pid, signal.SIGINT)   # what Ctrl-C in a terminal does: the whole foreground group
    _, err = run.communicate(timeout=120)
    return run, err, metrics


def test_ctrl_c_ends_with_the_command_that_resumes(tmp_path):
    overrides = _overrides("experiment.epochs=12")
    # The 12 epochs take a few seconds: on a loaded machine this test may be descheduled long enough that the run has
    # finished its last epoch and is exiting when the signal is sent, which then finds no process left to stop. Such a
    # try says nothing about Ctrl-C: another is made (a run that ignores Ctrl-C fails every try).
    for attempt in range(3):
        folder = tmp_path / f"try{attempt}"
        folder.mkdir()
        run, err, metrics = _interrupted_run(folder, overrides)
        finished = run.returncode == 0 and len(metrics.read_text().splitlines()) == 13
        if not finished:
            break
    assert run.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted; ") and "Resume with: " in last
    command = shlex.split(last.split("Resume with: ", 1)[1])
    assert command == ["surrol-data", "train", *overrides, "resume=true"]
    resumed = subprocess.run([*CLI, *command[1:]], cwd=folder, env=ENV, capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    assert [r["epoch"] for r in rows] == list(range(13))


def test_the_resume_command_keeps_the_overrides_and_replaces_resume_and_overwrite(monkeypatch):
    from surrol_data.train_app import resume_command

    monkeypatch.delenv("UV", raising=False)
    monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}/usr/bin")
    assert resume_command(["-m", "seed=0,1", "run_dir=my runs/x", "resume=false", "overwrite=true"]) == \
        "surrol-data train -m seed=0,1 'run_dir=my runs/x' resume=true"
    monkeypatch.setenv("UV", "/usr/bin/uv")   # started by `uv run`: the user's shell has no surrol-data on PATH
    assert resume_command(["seed=0"]) == "uv run surrol-data train seed=0 resume=true"


@pytest.mark.slow
def test_sigterm_stops_like_ctrl_c_with_quiet_workers_and_the_resume_command_as_run(tmp_path):
    """`kill PID` (or a scheduler's SIGTERM) mid-run: the finished epochs are kept, the env worker processes end
    without tracebacks or leaked semaphores, and the last line is the command that resumes, in the form the user
    ran it (here under `uv run`)."""
    overrides = _overrides("experiment.epochs=12", "experiment.n_envs=2")
    run = subprocess.Popen([*CLI, "train", *overrides], cwd=tmp_path, env={**ENV, "UV": "/usr/bin/uv"},
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    metrics = tmp_path / "run" / "metrics.jsonl"
    deadline = time.time() + 180
    while time.time() < deadline and run.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 2:
            break
        time.sleep(0.05)
    assert run.poll() is None, "the run ended before it could be stopped"
    run.send_signal(signal.SIGTERM)   # to the main process alone, as `kill PID` sends it
    _, err = run.communicate(timeout=120)
    assert run.returncode == 128 + signal.SIGTERM, err[-3000:]
    assert "Traceback" not in err and "leaked semaphore" not in err and "Error" not in err, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("stopped by SIGTERM; the finished epochs are saved. Resume with: uv run surrol-data train ")
    assert shlex.split(last.split("Resume with: ", 1)[1]) == ["uv", "run", "surrol-data", "train", *overrides,
                                                             "resume=true"]
    import torch

    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    checkpoint = torch.load(tmp_path / "run" / "checkpoint.pt", map_location="cpu", weights_only=True)
    assert checkpoint["state"]["epoch"] == rows[-1]["epoch"] >= 1   # the last finished epoch, whole, to resume from


def test_sigterm_reaches_the_train_command_as_a_stop_with_the_resume_line(monkeypatch, capsys):
    """The signal path alone, in this process: SIGTERM becomes the interrupt that ends with the resume line and
    status 143 (the run above shows the workers' side)."""
    from surrol_data import train_app

    def stopped_run(args, argv):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(30)   # the signal interrupts this
        raise AssertionError("SIGTERM did not stop the run")

    monkeypatch.setattr(train_app, "_main", stopped_run)
    monkeypatch.setenv("UV", "/usr/bin/uv")
    with pytest.raises(SystemExit) as stop:
        train_app.main(["seed=3"])
    assert stop.value.code == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip().endswith("Resume with: uv run surrol-data train seed=3 resume=true")
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL   # put back as it was


def test_the_core_install_trains_without_tensorboard_and_a_failed_start_leaves_nothing(tmp_path, monkeypatch,
                                                                                       capsys):
    """TensorBoard is an extra: by default (tensorboard=auto) a run without it logs none and says so in one line;
    tensorboard=true without it stops before any file is written, so the same command runs again once fixed."""
    from hydra import compose, initialize_config_dir

    from surrol_data import extras
    from surrol_data.algos.train import train
    from surrol_data.train_app import _run, config_dir, tensorboard_wanted, to_train_config

    real_require = extras.require

    def without_tensorboard(module):
        if module == "tensorboard":
            raise extras.MissingExtra(extras.install_hint(module))
        return real_require(module)

    import importlib.util

    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "tensorboard" else real_find_spec(name, *a))
    monkeypatch.setattr(extras, "require", without_tensorboard)
    assert tensorboard_wanted("auto") is False and tensorboard_wanted(True) is True
    run_dir = tmp_path / "run"
    overrides = [o for o in _overrides("experiment.epochs=1", "progress=false") if not o.startswith(("run_dir",
                                                                                                   "tensorboard"))]
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        asked = compose("config", overrides=[*overrides, f"run_dir={run_dir}", "tensorboard=true"])
        default = compose("config", overrides=[*overrides, f"run_dir={run_dir}"])
    assert default.tensorboard == "auto"
    with pytest.raises(extras.MissingExtra, match=r"surrol-data\[tensorboard\]"):
        train(to_train_config(asked))
    assert not any(p.is_file() for p in run_dir.rglob("*"))   # nothing that would refuse the next start
    capsys.readouterr()
    _run(default)   # what `surrol-data train` runs, outside a sweep
    said = capsys.readouterr()
    assert "note: no TensorBoard logs (the tensorboard extra is not installed" in " ".join(said.err.split())
    assert said.out.startswith("trained SurRoL/NeedleReach-v0 for 1 epoch(s)")
    assert (run_dir / "policy.pt").is_file() and not (run_dir / "tb").exists()


def test_the_sweep_table_prints_an_install_hint_with_its_brackets(tmp_path, capsys, monkeypatch):
    from surrol_data.extras import install_hint

    monkeypatch.setenv("COLUMNS", "400")   # each cell on one line
    from surrol_data.train_app import _print_sweep_report

    report = tmp_path / "jobs.jsonl"
    report.write_text(json.dumps({"num": 0, "job": "seed=0", "status": "failed", "run_dir": "runs/x[0]",
                                  "detail": install_hint("tensorboard")}) + "\n")
    assert _print_sweep_report(report, ["seed=0"], cluster=False) == 1
    table = " ".join(capsys.readouterr().err.split())
    assert "pip install 'surrol-data[tensorboard]'" in table and "runs/x[0]" in table


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

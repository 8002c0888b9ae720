"""Sweeps, the study and sharded collections on a real SLURM: slurmctld and slurmd on this machine
(``tests/slurm_cluster.py``), two CPUs, one CPU per job. Skipped, naming the Debian packages, without them."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from slurm_cluster import SlurmCluster, missing

pytestmark = [pytest.mark.slurm, pytest.mark.skipif(missing() is not None, reason=missing() or "")]

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "surrol_data.cli"]
# What every job asks for on the 2-CPU test node: one CPU, so that two jobs run at once.
JOB = ["hydra/launcher=slurm", "hydra.launcher.cpus_per_task=1", "hydra.launcher.mem_gb=1",
       "hydra.launcher.timeout_min=60"]
SLURM = ["--launcher", "slurm", "--cpus", "1", "--mem-gb", "1", "--time", "60"]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    with SlurmCluster(tmp_path_factory.mktemp("slurm")) as c:
        yield c


def _env(cluster) -> dict:
    # the jobs inherit the submitting environment (sbatch --export=ALL): this checkout and the cluster's config;
    # wide output, so that no message or table cell is folded where a test reads it
    return {**cluster.env, "PYTHONPATH": str(REPO), "HF_HUB_OFFLINE": "1", "COLUMNS": "250"}


@pytest.fixture(scope="module")
def reach_demos(tmp_path_factory):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("demos") / "NeedleReach_script"
    collect_script("NeedleReach", 6, root, progress=False)
    return root


def _train_overrides(demos_root, *extra):
    return ["algo=ddpgbc", "demos=script", "demos.num=4", f"demos_root={demos_root}", "experiment=smoke",
            "run_dir=sweep/${task.name}/seed${seed}", "hydra.sweep.dir=multirun", "progress=false",
            "tensorboard=false", "algo.params.hidden_sizes=[32,32]", *extra]


def test_a_sweep_runs_as_slurm_jobs_and_reports_the_failed_one(cluster, reach_demos, tmp_path):
    # 4 jobs: the two NeedlePick ones fail (no NeedlePick demos in demos_root), the two NeedleReach ones train
    result = subprocess.run([*CLI, "train", "-m", *JOB, "seed=0,1", "task=NeedleReach,NeedlePick",
                             *_train_overrides(reach_demos.parent)], cwd=tmp_path,
                            env=_env(cluster), capture_output=True, text=True, timeout=1800)
    assert result.returncode == 1, result.stderr[-3000:]
    table = result.stderr[result.stderr.index("sweep: 4 job(s)"):]
    assert len(re.findall(r"\bok\b", table)) == 2 and len(re.findall(r"\bfailed\b", table)) == 2, table
    assert table.count("NeedlePick_script does not exist") == 2 and "Traceback" not in result.stderr, table
    # the runs' folders are where a local sweep puts them, each trained in its own SLURM job
    procs = [json.loads((tmp_path / "sweep" / "NeedleReach" / f"seed{s}" / "process.json").read_text())
             for s in (0, 1)]
    assert procs[0]["pid"] != procs[1]["pid"] and all(p["epochs_done"] == 3 for p in procs)
    # Hydra's job folders as locally, and each job's SLURM log beside them
    assert sorted(p.name for p in (tmp_path / "multirun").iterdir() if p.name.isdigit()) == ["0", "1", "2", "3"]
    logs = sorted((tmp_path / "multirun" / ".submitit").glob("*_log.out"))
    assert len(logs) == 4 and all("Starting with JobEnvironment" in p.read_text() for p in logs)
    assert not list(tmp_path.glob(".surrol_sweep_*"))   # the jobs' report file is cleaned up
    cluster.wait_empty()


def test_a_requeued_job_resumes_from_its_checkpoint(cluster, reach_demos, tmp_path):
    epochs = 20     # about 10 s of training left when the job is requeued (a smoke epoch: ~0.5 s)
    run = tmp_path / "sweep" / "NeedleReach" / "seed0"
    sweep = subprocess.Popen([*CLI, "train", "-m", *JOB, "seed=0", "task=NeedleReach", "resume=true",
                              *_train_overrides(reach_demos.parent, f"experiment.epochs={epochs}")], cwd=tmp_path,
                             env=_env(cluster), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 1500
        while not (run / "metrics.jsonl").is_file() or len((run / "metrics.jsonl").read_text().splitlines()) < 3:
            assert sweep.poll() is None and time.monotonic() < deadline, sweep.communicate()[1][-3000:]
            time.sleep(0.5)
        job = cluster.squeue().split()[0]       # the one job: epochs 0 and 1 (at least) done and checkpointed
        cluster.requeue(job)
        _, err = sweep.communicate(timeout=1500)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert sweep.returncode == 0, err[-3000:]
    process = json.loads((run / "process.json").read_text())
    # it resumed from a checkpoint: not from zero, and not after the run had finished
    assert process["resumed_after_epoch"] is not None and 1 <= process["resumed_after_epoch"] < epochs, process
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == list(range(epochs + 1))
    restarts = subprocess.run(["scontrol", "show", "job", job], env=cluster.env, capture_output=True, text=True)
    assert "Restarts=1" in restarts.stdout, restarts.stdout   # SLURM ran the same job twice
    cluster.wait_empty()


def _report_numbers(out: Path) -> str:
    """The report's Table I section (the numbers; not the provenance, which names job, time and machine)."""
    text = (out / "report.md").read_text()
    start = text.index("## Table I")
    return text[start:text.index("\n## ", start + 1)]


def _run_numbers(folder: Path) -> tuple[str, str]:
    """A run's per-epoch metrics and per-episode evaluation, without timings and batch size."""
    import pandas as pd

    metrics = pd.read_csv(folder / "metrics.csv")
    metrics = metrics[[c for c in metrics.columns if not c.startswith("time_") and c not in ("wall_s",
                                                                                           "batched_members")]]
    return metrics.to_csv(index=False), pd.read_csv(folder / "eval_episodes.csv").to_csv(index=False)


def _study_on_slurm_equals_local(cluster, tmp_path: Path, sources: list[str], cancel_first: bool = False) -> None:
    """table1_quick (one seed, ``sources``) on SLURM, one job per run, against the same runs trained here one at a
    time (`--next 1`: a batch of one, as each job trains; a local batch of several differs from single runs by
    floating-point rounding, docs/training.md#batched-path): every metric of every epoch and every evaluation
    episode equal, and so the report's Table I. ``cancel_first``: the first submission's jobs are cancelled;
    ``--report`` shows them failed, and the same command submits them again."""
    from typer.testing import CliRunner

    from surrol_data.cli import app

    quick = ["--override", "experiment.study.seeds=[0]",
             "--override", f"experiment.study.sources=[{','.join(sources)}]"]
    local = tmp_path / "local"
    for _ in sources:
        result = CliRunner().invoke(app, ["study", "table1_quick", "--out", str(local), *quick, "--next", "1"])
        assert result.exit_code == 0, result.output
    on_slurm = tmp_path / "slurm"
    env = _env(cluster)
    # the same demo sets: built once here and copied (each job checks them against the hashes the runs record)
    on_slurm.mkdir()
    subprocess.run(["cp", "-r", str(local / "demos"), str(on_slurm / "demos")], check=True)
    if cancel_first:
        first = subprocess.run([*CLI, "study", "table1_quick", "--out", str(on_slurm), *quick, *SLURM], env=env,
                               capture_output=True, text=True, timeout=600)
        assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
        jobs = [json.loads(line) for line in (on_slurm / "slurm" / "jobs.jsonl").read_text().splitlines()]
        subprocess.run(["scancel", *(j["job_id"] for j in jobs)], env=cluster.env, check=True)
        cluster.wait_empty()
        report = subprocess.run([*CLI, "study", "table1_quick", "--out", str(on_slurm), *quick, "--report"], env=env,
                                capture_output=True, text=True, timeout=600)
        assert report.returncode == 0, report.stdout + report.stderr
        for source in sources:
            assert re.search(rf"{source}/0\s.*failed", report.stdout), report.stdout
    submitted = subprocess.run([*CLI, "study", "table1_quick", "--out", str(on_slurm), *quick, *SLURM, "--wait"],
                               env=env, capture_output=True, text=True, timeout=3600)
    assert submitted.returncode == 0, submitted.stdout[-3000:] + submitted.stderr[-3000:]
    assert f"submitted {len(sources)} SLURM job(s), one per run" in submitted.stdout
    if cancel_first:
        assert len((on_slurm / "slurm" / "jobs.jsonl").read_text().splitlines()) == 2 * len(sources)
    runs = sorted(p.parent.relative_to(on_slurm / "runs").as_posix() for p in (on_slurm / "runs").rglob("run.json"))
    assert runs == sorted(f"{source}/seed0" for source in sources)
    assert not any((on_slurm / ".work").rglob("checkpoint.pt"))     # no run left half-trained
    for run in runs:
        record = json.loads((on_slurm / "runs" / run / "run.json").read_text())
        assert record["time"]["batched_members"] == 1 and record["epochs"] == 2
        assert _run_numbers(on_slurm / "runs" / run) == _run_numbers(local / "runs" / run), run
    assert _report_numbers(on_slurm) == _report_numbers(local)
    # nothing left to do: submitting again submits nothing
    again = subprocess.run([*CLI, "study", "table1_quick", "--out", str(on_slurm), *quick, *SLURM], env=env,
                           capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and "nothing to submit" in again.stdout, again.stdout + again.stderr


def test_a_study_run_cancelled_on_slurm_is_shown_failed_resubmitted_and_gives_the_local_numbers(cluster, tmp_path):
    """One run (script/0) in one job, cancelled, then submitted again: what the two tests below show (the whole study,
    and a failed job beside a finished one), at a third of their cost, in the default run."""
    _study_on_slurm_equals_local(cluster, tmp_path, ["script"], cancel_first=True)


@pytest.mark.slow
def test_the_study_on_slurm_gives_the_local_numbers(cluster, tmp_path):
    """All three sources, three jobs (two at a time on the two-CPU node)."""
    _study_on_slurm_equals_local(cluster, tmp_path, ["script", "novice", "expert"])


@pytest.mark.slow
def test_a_failed_study_job_is_shown_and_resubmitted_alone(cluster, tmp_path):
    """One run's job is cancelled: --report shows it failed, and the same command submits that run only. (Two seeds
    of one source: one demo set to build.)"""
    quick = ["--override", "experiment.study.seeds=[0,1]", "--override", "experiment.study.sources=[script]"]
    out = tmp_path / "study"
    env = _env(cluster)
    first = subprocess.run([*CLI, "study", "table1_quick", "--out", str(out), *quick, *SLURM], env=env,
                           capture_output=True, text=True, timeout=1800)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    jobs = [json.loads(line) for line in (out / "slurm" / "jobs.jsonl").read_text().splitlines()]
    assert [(j["source"], j["seed"]) for j in jobs] == [("script", 0), ("script", 1)]
    subprocess.run(["scancel", jobs[1]["job_id"]], env=cluster.env, check=True)
    cluster.wait_empty()
    report = subprocess.run([*CLI, "study", "table1_quick", "--out", str(out), *quick, "--report"], env=env,
                            capture_output=True, text=True, timeout=600)
    assert report.returncode == 0, report.stdout + report.stderr
    assert re.search(r"script/0\s.*finished", report.stdout) and re.search(r"script/1\s.*failed", report.stdout)
    again = subprocess.run([*CLI, "study", "table1_quick", "--out", str(out), *quick, *SLURM, "--wait"], env=env,
                           capture_output=True, text=True, timeout=1800)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "submitted 1 SLURM job(s), one per run: script/1" in again.stdout
    assert len((out / "slurm" / "jobs.jsonl").read_text().splitlines()) == 3
    assert (out / "runs" / "script" / "seed1" / "run.json").is_file() and (out / "report.md").is_file()


@pytest.fixture(scope="module")
def one_process(cluster, tmp_path_factory) -> Path:
    """5 NeedleReach script episodes collected by one process: what both sharded collections are compared with."""
    out = tmp_path_factory.mktemp("one_process") / "one"
    one = subprocess.run([*CLI, "collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "5",
                          "--out", str(out)], env=_env(cluster), capture_output=True, text=True, timeout=900)
    assert one.returncode == 0, one.stdout + one.stderr
    return out


@pytest.mark.parametrize("launcher", ["local", "slurm"])
def test_sharded_collection_equals_one_process_by_seed(cluster, one_process, tmp_path, launcher):
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.validate import validate_dataset

    extra = SLURM if launcher == "slurm" else []
    sharded = subprocess.run([*CLI, "collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "5",
                              "--shards", "2", "--out", str(tmp_path / "merged"), *extra], env=_env(cluster),
                             capture_output=True, text=True, timeout=1800)
    assert sharded.returncode == 0, sharded.stdout[-3000:] + sharded.stderr[-3000:]
    shards = [DatasetReader(p) for p in sorted((tmp_path / "merged.shards").glob("shard*"))]
    assert [sorted(r.episodes["seed"]) for r in shards] == [[0, 2, 4], [1, 3]]    # disjoint seeds
    merged, single = DatasetReader(tmp_path / "merged"), DatasetReader(one_process)
    assert sorted(merged.episodes["seed"]) == sorted(single.episodes["seed"]) == [0, 1, 2, 3, 4]
    by_seed = dict(zip(single.episodes["seed"], single.episodes["episode_index"]))
    for seed, ep in zip(merged.episodes["seed"], merged.episodes["episode_index"]):
        a, b = merged.trajectory(int(ep)), single.trajectory(int(by_seed[seed]))
        for key in ("observation", "action", "reward", "tip_position"):
            assert (getattr(a, key) == getattr(b, key)).all(), (seed, key)
    provenance = ["source", "operator_id", "skill", "seed"]
    assert merged.episodes.sort_values("seed")[provenance].reset_index(drop=True).equals(
        single.episodes.sort_values("seed")[provenance].reset_index(drop=True))
    assert validate_dataset(tmp_path / "merged") == []

"""The study on a SLURM cluster: one job per pending run (a job array), each writing its run folder as a local
batch does; the report is assembled from the finished runs whenever asked (``study ... --report``).

    surrol-data study table1 --out docs/results/table1 --launcher slurm --partition cpu --time 720
    surrol-data study table1 --out docs/results/table1 --report     # which jobs are done / failed, the report

Each job trains its run as a batch of one in ``OUT/.work/<source>/seed<k>`` (checkpoints: a requeued or
resubmitted job resumes) and moves it into ``OUT/runs/<source>/seed<k>`` when done. ``OUT/slurm/jobs.jsonl``
records which job was given which run; ``OUT/slurm/<job id>_0_log.out`` (and ``.err``) is each job's log. Submitting again submits
only the runs that are neither finished nor queued or running, so a failed or cancelled job is re-submitted by
the same command and no finished run is redone.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from surrol_data.slurm import ACTIVE, SlurmError, SlurmOptions, queue_states, submit_array, wait_for
from surrol_data.study.demo_sets import demo_quality, demo_quality_markdown
from surrol_data.study.runs import _checked_configs, finished_runs, prepare_demo_sets, study_spec, train_one_run
from surrol_data.study.spec import StudySpec, parse_runs, run_name

JOBS = Path("slurm") / "jobs.jsonl"


@dataclass(frozen=True)
class RunJob:
    """Where one run of the study stands on the cluster."""
    run: tuple[str, int]
    state: str          # finished, a SLURM state (PENDING, RUNNING, ...), failed (left the queue unfinished),
    job_id: str = ""    # or "not submitted"
    log: str = ""


def submitted_jobs(out: Path) -> dict[tuple[str, int], dict]:
    """Each run's latest job (``OUT/slurm/jobs.jsonl``)."""
    path = out / JOBS
    latest = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            if line.strip():
                entry = json.loads(line)
                latest[(entry["source"], int(entry["seed"]))] = entry
    return latest


def run_jobs(out: Path, spec: StudySpec) -> list[RunJob]:
    """Every run of the study: finished, queued or running (its SLURM state), failed, or not submitted."""
    out = Path(out)
    done = set(finished_runs(out, spec))
    jobs = submitted_jobs(out)
    pending = [jobs[r]["job_id"] for r in spec.run_order() if r in jobs and r not in done]
    try:
        states = queue_states(pending) if pending else {}
    except SlurmError:   # e.g. the results copied off the cluster: whether a job still runs cannot be told here
        states = {job_id: "unknown (no squeue here)" for job_id in pending}
    rows = []
    for run in spec.run_order():
        entry = jobs.get(run, {})
        job_id, log = entry.get("job_id", ""), entry.get("stderr", "")
        if run in done:
            rows.append(RunJob(run, "finished", job_id))
        elif not entry:
            rows.append(RunJob(run, "not submitted"))
        else:
            rows.append(RunJob(run, states.get(job_id, "failed"), job_id, log))
    return rows


def submit_study(experiment: str, out: str | Path, options: SlurmOptions, *, natural: bool = False,
                 overrides: Sequence[str] = (), runs: str | None = None, next_runs: int | None = None,
                 build_demos: bool = False, progress: bool = True, say=print) -> list[RunJob]:
    """Submit one SLURM job per selected run (``runs`` by name, else the next ``next_runs`` pending, else all
    pending), leaving out runs that are finished or already queued or running. The demo sets are built (or
    checked) here first, and the code identity is checked here before anything is submitted."""
    spec = study_spec(experiment, overrides, natural)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    sets, _ = prepare_demo_sets(spec, out, build=build_demos, progress=progress)
    (out / "demos.md").write_text(f"# Demonstrations\n\n{demo_quality_markdown(demo_quality(sets, spec.task), spec.matched, spec.task)}")
    standing = {job.run: job for job in run_jobs(out, spec)}
    busy = [r for r, job in standing.items() if job.state in ACTIVE]
    if runs:
        selected = parse_runs(runs, spec)
        finished = [run_name(*r) for r in selected if standing[r].state == "finished"]
        if finished:
            raise ValueError(f"run(s) {', '.join(finished)} are finished already (in {out / 'runs'}); to redo one, "
                             "delete its folder first")
    else:
        selected = [r for r in spec.run_order() if standing[r].state != "finished"]
    if busy and any(r in busy for r in selected):
        say(f"already queued or running, not submitted again: "
            f"{', '.join(f'{run_name(*r)} (job {standing[r].job_id})' for r in selected if r in busy)}")
    selected = [r for r in selected if r not in busy]
    if next_runs is not None and not runs:
        selected = selected[:next_runs]
    if not selected:
        say("nothing to submit: every selected run is finished, queued or running")
        return list(standing.values())
    _checked_configs(spec, experiment, out, sets, selected[:1], False)   # refuse before the cluster spends time
    job = functools.partial(train_one_run, experiment, str(out), natural=natural, overrides=tuple(overrides))
    jobs = submit_array(job, selected, out / "slurm", f"{spec.experiment}", options)
    with open(out / JOBS, "a") as f:
        for (source, seed), j in zip(selected, jobs):
            f.write(json.dumps({"source": source, "seed": seed, "job_id": j.job_id,
                                "submitted": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "stdout": str(j.paths.stdout),
                                "stderr": str(j.paths.stderr)}) + "\n")
    say(f"submitted {len(jobs)} SLURM job(s), one per run: "
        f"{', '.join(f'{run_name(*r)} → {j.job_id}' for r, j in zip(selected, jobs))}")
    say(f"logs: {out / 'slurm'}/<job id>_0_log.out; when they are done: surrol-data study {experiment} --out {out} --report")
    return run_jobs(out, spec)


def wait_for_runs(out: str | Path, spec: StudySpec, say=print) -> list[RunJob]:
    """Until no run of the study is queued or running; where each run then stands."""
    ids = [job.job_id for job in run_jobs(Path(out), spec) if job.state in ACTIVE]
    wait_for(ids, say)
    return run_jobs(Path(out), spec)


"""SLURM job arrays for the commands that fan out over a cluster (``study --launcher slurm``,
``collect --shards N --launcher slurm``): submit a function once per item through submitit, and see which jobs
are still queued or running.

Job states come from ``squeue``, which every cluster has, not from ``sacct``, which needs the accounting database:
a job that left the queue either left its result (a finished run folder, a shard dataset: the caller looks) or
failed, and its log says why. Training sweeps (``train -m hydra/launcher=slurm``) go through Hydra's submitit
launcher instead (``configs/hydra/launcher/slurm.yaml``).
"""

from __future__ import annotations

import getpass
import shutil
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from surrol_data.extras import require

ACTIVE = ("PENDING", "CONFIGURING", "RUNNING", "COMPLETING", "REQUEUED", "REQUEUE_FED", "REQUEUE_HOLD", "RESIZING",
          "SUSPENDED", "STOPPED", "SIGNALING", "STAGE_OUT", "PREEMPTED", "RESV_DEL_HOLD", "SPECIAL_EXIT")


_SQUEUE_TRIES = 6


class SlurmError(RuntimeError):
    """No SLURM to submit to, or it refused the jobs (the message says what to do)."""


@dataclass(frozen=True)
class SlurmOptions:
    """What each job asks the scheduler for (``sbatch`` options)."""
    partition: str | None = None
    account: str | None = None
    time_min: int = 1440
    mem_gb: float = 4.0
    cpus_per_task: int = 2
    array_parallelism: int = 64          # at most this many of the array's jobs run at once
    extra: dict[str, str] = field(default_factory=dict)   # further sbatch options, e.g. {"qos": "normal"}


def parse_sbatch_options(items: Sequence[str]) -> dict[str, str]:
    """``["qos=normal", "constraint=avx2"]`` → ``{"qos": "normal", "constraint": "avx2"}`` (``--sbatch`` values)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--sbatch takes KEY=VALUE (an sbatch option without its dashes, e.g. qos=normal); "
                             f"got {item!r}")
        out[key.strip().lstrip("-")] = value.strip()
    return out


def _check_slurm() -> None:
    missing = [exe for exe in ("sbatch", "squeue", "srun") if shutil.which(exe) is None]
    if missing:
        raise SlurmError(f"no SLURM here ({', '.join(missing)} not on PATH): run this on a login node of a SLURM "
                         "cluster, or leave out --launcher slurm to run locally")


def submit_array(fn: Callable, items: Sequence[tuple], folder: Path, name: str, options: SlurmOptions) -> list:
    """Submit ``fn(*item)`` for each item as one job array; the submitit jobs, in item order. Each job's log is
    ``folder/<array id>_<index>_0_log.out`` (and ``.err``).

    One folder for all jobs, made before ``sbatch``: with a folder per job (submitit's ``%j``) submitit makes it
    only after ``sbatch`` returned, and a job that an idle cluster starts at once finds no folder for its log and
    fails before it runs."""
    _check_slurm()
    submitit = require("submitit")
    executor = submitit.AutoExecutor(folder=str(folder), cluster="slurm")
    params = {"name": name, "timeout_min": int(options.time_min), "cpus_per_task": int(options.cpus_per_task),
              "mem_gb": options.mem_gb, "slurm_array_parallelism": int(options.array_parallelism)}
    if options.partition:
        params["slurm_partition"] = options.partition
    if options.account:
        params["slurm_account"] = options.account
    if options.extra:
        params["slurm_additional_parameters"] = dict(options.extra)
    executor.update_parameters(**params)
    try:
        return executor.map_array(fn, *zip(*items))
    except (submitit.core.utils.FailedJobError, submitit.core.utils.FailedSubmissionError) as e:
        detail = " ".join(str(e).split())
        raise SlurmError(f"sbatch refused the jobs: {detail} (check --partition, --account, --time, --mem-gb "
                         "and --cpus against `sinfo`)") from None


def queue_states(job_ids: Sequence[str]) -> dict[str, str]:
    """The state (PENDING, RUNNING, REQUEUED, ...) of each of ``job_ids`` still in the queue; jobs that left it
    are absent. Array tasks are named ``<array id>_<index>``."""
    if not job_ids:
        return {}
    _check_slurm()
    for attempt in range(_SQUEUE_TRIES):   # a busy slurmctld drops a request now and then: ask again
        out = subprocess.run(["squeue", "-h", "-r", "-u", getpass.getuser(), "-o", "%i|%T"], capture_output=True,
                             text=True)
        if out.returncode == 0:
            break
        time.sleep(2.0 * (attempt + 1))
    else:
        raise SlurmError(f"squeue failed {_SQUEUE_TRIES} times (is slurmctld up? `sinfo` says): "
                         f"{out.stderr.strip() or f'exit status {out.returncode}'}")
    wanted = set(job_ids)
    states = {}
    for line in out.stdout.splitlines():
        job, _, state = line.strip().partition("|")
        if job in wanted:
            states[job] = state
    return states


def wait_for(job_ids: Sequence[str], say: Callable[[str], None] = print, poll_s: float = 5.0) -> None:
    """Until none of ``job_ids`` is queued or running, saying how many are left whenever that changes."""
    left = None
    while True:
        active = [j for j, state in queue_states(job_ids).items() if state in ACTIVE]
        if len(active) != left:
            left = len(active)
            say(f"SLURM: {len(job_ids) - left} of {len(job_ids)} job(s) done, {left} queued or running")
        if not active:
            return
        time.sleep(poll_s)

"""The Hydra app behind ``surrol-data train``: compose configs/ into a :class:`TrainConfig` and run it.

    surrol-data train algo=ddpgbc task=NeedlePick demos=script seed=0
    surrol-data train -m seed=0,1,2,3 demos=script,novice,expert       # local parallel sweep (joblib)
    surrol-data train -m hydra/launcher=slurm seed=0,1,2                # the same sweep on SLURM (submitit)
    surrol-data train resume=true ...same overrides...                  # continue a killed run
    surrol-data train -m batched=true seed=0,1,2,3 demos=script,novice,expert   # the sweep as one batched ensemble

Where the configs are: the repository's ``configs/`` folder, found next to the package of a source checkout
(the project is installed editable from its clone, ``uv sync``'s default). A different folder can be
given with ``SURROL_DATA_CONFIGS=/path/to/configs`` or Hydra's own ``--config-dir``. A wheel build that
should carry them can map ``configs`` to ``surrol_data/configs`` (hatch ``force-include``), which is looked
at first.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import signal
import sys
import tempfile
import threading
import traceback
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from surrol_data.algos.demos import DemoSpec
from surrol_data.algos.train import Schedule, TrainConfig, train

CONFIG_ENV_VAR = "SURROL_DATA_CONFIGS"


def config_dir() -> Path:
    """The configs folder: $SURROL_DATA_CONFIGS, else configs shipped in the package, else the repo's configs/."""
    candidates = [Path(os.environ[CONFIG_ENV_VAR])] if os.environ.get(CONFIG_ENV_VAR) else []
    here = Path(__file__).resolve().parent
    candidates += [here / "configs", here.parent / "configs"]
    for path in candidates:
        if (path / "config.yaml").is_file():
            return path
    raise FileNotFoundError(f"no Hydra configs found (looked for config.yaml in {[str(p) for p in candidates]}); "
                            f"run from a clone of the repository or set {CONFIG_ENV_VAR}")


def to_train_config(cfg: DictConfig) -> TrainConfig:
    """The composed Hydra config as the typed config of :func:`surrol_data.algos.train.train`."""
    algo, exp, demos = cfg.algo, cfg.experiment, cfg.demos
    schedule_fields = set(Schedule.__dataclass_fields__)
    schedule = {k: v for k, v in OmegaConf.to_container(exp, resolve=True).items() if k in schedule_fields}
    schedule.update({k: algo[k] for k in ("offline_steps", "warmup_steps", "her_k", "demos_in_replay", "online")
                     if k in algo})
    demo_path = demos.path
    if demo_path is not None:
        demo_path = hydra.utils.to_absolute_path(str(demo_path))
    return TrainConfig(
        env_id=str(cfg.task.env_id),
        run_dir=hydra.utils.to_absolute_path(str(cfg.run_dir)),
        learner=str(algo.learner),
        learner_params=OmegaConf.to_container(algo.params, resolve=True),
        demos=DemoSpec(path=demo_path, where=OmegaConf.to_container(demos.where, resolve=True),
                       num=int(demos.num), successful_only=bool(demos.successful_only),
                       frames=str(demos.get("frames", "all"))),
        schedule=Schedule(**schedule),
        seed=int(cfg.seed),
        resume=bool(cfg.resume),
        overwrite=bool(cfg.get("overwrite", False)),
        progress=bool(cfg.progress),
        tensorboard=tensorboard_wanted(cfg.get("tensorboard", "auto")),
    )


def tensorboard_wanted(setting) -> bool:
    """``tensorboard=auto`` (the default): TensorBoard logs where the ``tensorboard`` extra is installed, none on the
    core install; ``true`` asks for them (the run stops before it starts, naming the extra, where it is missing)."""
    if str(setting).lower() == "auto":
        import importlib.util

        return importlib.util.find_spec("tensorboard") is not None
    return bool(setting)


SWEEP_REPORT_VAR = "SURROL_DATA_SWEEP_REPORT"


def _in_sweep() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    try:
        return HydraConfig.get().mode == RunMode.MULTIRUN
    except ValueError:
        return False


def _job_label() -> str:
    from hydra.core.hydra_config import HydraConfig

    try:
        return " ".join(HydraConfig.get().overrides.task) or "(defaults)"
    except ValueError:
        return ""


def _job_num() -> int | None:
    from hydra.core.hydra_config import HydraConfig

    try:
        return int(HydraConfig.get().job.num)
    except (ValueError, TypeError):
        return None


def _report_job(status: str, detail: str, run_dir: str) -> None:
    path = os.environ.get(SWEEP_REPORT_VAR)
    if not path:
        return
    line = json.dumps({"num": _job_num(), "job": _job_label(), "status": status, "detail": detail,
                       "run_dir": run_dir})
    with open(path, "a") as f:  # one short O_APPEND write per job: parallel workers do not interleave
        f.write(line + "\n")


def _run(cfg: DictConfig) -> float:
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.extras import MissingExtra

    sweep = _in_sweep()
    run_dir = str(cfg.get("run_dir", ""))
    try:
        train_cfg = to_train_config(cfg)
        if str(cfg.get("tensorboard")).lower() == "auto" and not train_cfg.tensorboard:
            print("note: no TensorBoard logs (the tensorboard extra is not installed: `uv sync --extra tensorboard` "
                  "or `pip install 'surrol-data[tensorboard]'`); metrics.csv holds every epoch", file=sys.stderr)
        rows = train(train_cfg)
    except (FileNotFoundError, FileExistsError, ValueError, DatasetError, MissingExtra) as e:
        # bad input: say what and how to fix, no traceback; in a sweep the other jobs still run
        print(f"error: {e}", file=sys.stderr)
        if sweep:
            _report_job("failed", str(e), run_dir)
            return float("nan")
        raise SystemExit(2) from None
    except Exception as e:
        if not sweep:
            raise
        _report_job("failed", f"{type(e).__name__}: {e}", run_dir)
        traceback.print_exc()
        return float("nan")
    success = float(rows[-1]["success_rate"]) if rows else float("nan")
    if sweep:
        _report_job("ok", f"final success {success:.2f}", run_dir)  # the sweep's table says where each run is
    else:
        _print_outputs(train_cfg, rows)
    return success  # the sweeper's return value: final evaluation success


def _shown(path: Path) -> str:
    """``path`` relative to the launch folder when it lies under it (what the user typed), else absolute."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _print_outputs(cfg: TrainConfig, rows: list[dict]) -> None:
    """Where a finished single run left its outputs."""
    run_dir = Path(cfg.run_dir)
    last = rows[-1] if rows else {}
    print(f"trained {cfg.env_id} for {last.get('epoch', 0)} epoch(s): final success "
          f"{float(last.get('success_rate', float('nan'))):.2f}")
    outputs = [("run folder", run_dir), ("policy", run_dir / "policy.pt"), ("metrics", run_dir / "metrics.csv")]
    if (run_dir / "tb").is_dir():
        outputs.append(("tensorboard", run_dir / "tb"))
    for label, path in outputs:
        print(f"  {label:<12} {_shown(path)}")


def _from_interrupt(e: BaseException) -> bool:
    """Ctrl-C, or an error raised while unwinding from it (e.g. by env workers that got the SIGINT too)."""
    seen = set()
    while e is not None and id(e) not in seen and not isinstance(e, SystemExit):
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


# Which signal stopped the run (set by the handlers below): the exit status and the message name it.
_stopped_by: list[int] = []


@contextlib.contextmanager
def _quiet_workers_after_ctrl_c():
    """Ctrl-C reaches the env worker processes too, and gymnasium relays each one's KeyboardInterrupt traceback
    as a warning while the run shuts down; after a Ctrl-C those are silenced (the resume message says it all).
    SIGTERM (``kill``, ``timeout``, a job scheduler) stops the run the same way: the finished epochs are
    checkpointed already, the env workers are closed rather than orphaned (no tracebacks from them, no leaked
    semaphores), and the same resume message ends it."""
    import gymnasium.logger

    if threading.current_thread() is not threading.main_thread():
        yield  # signals go to the main thread only
        return
    level = gymnasium.logger.min_level
    # Python's own SIGINT handler and the default SIGTERM action are replaced; a caller's own handler (submitit's,
    # which requeues a SLURM job) or an ignored signal (SIGINT in a background job) is left alone.
    ours = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL}
    ours = {signum: default for signum, default in ours.items() if signal.getsignal(signum) is default}

    def on_stop(signum, frame):
        gymnasium.logger.min_level = gymnasium.logger.ERROR + 1
        if _stopped_by:
            return   # a second signal while unwinding from the first is not raised again
        _stopped_by.append(signum)
        raise KeyboardInterrupt   # the run's clean-up ends the env workers (algos.train)

    _stopped_by.clear()
    for signum in ours:
        signal.signal(signum, on_stop)
    try:
        yield
    finally:
        for signum, default in ours.items():
            signal.signal(signum, default)
        gymnasium.logger.min_level = level


def resume_command(args: list[str]) -> str:
    """The command that continues an interrupted ``surrol-data train ARGS``: the same overrides plus resume=true,
    in the form that runs in the user's shell (``uv run surrol-data ...`` under uv)."""
    import shlex

    from surrol_data.viz.open_command import as_run_here

    kept = [a for a in args if a.split("=", 1)[0].lstrip("+") not in ("resume", "overwrite")]
    return f"{as_run_here('surrol-data', 'surrol_data.cli')} {shlex.join(['train', *kept, 'resume=true'])}"


def _print_sweep_report(path: Path, expected: list[str], cluster: bool) -> int:
    """A table of every job of the sweep (``expected``: each job's overrides, by job number); the number that
    failed. Once any job has reported, one that left no line (killed by the OS or the scheduler: out of memory,
    out of time, cancelled) is a failed row too; if none reported, Hydra's own error (a bad override, ...) says it."""
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
    if not rows:
        return 0
    seen = {r.get("num") for r in rows}
    where = ("its SLURM log: <sweep dir>/.submitit/<job id>_<num>_0_log.err" if cluster else "the sweep's output above")
    rows += [{"num": num, "job": job, "status": "failed", "run_dir": "",
              "detail": f"no result: the job was killed or never ran (job #{num}; see {where})"}
             for num, job in enumerate(expected) if num not in seen]
    rows.sort(key=lambda r: (r.get("num") is None, r.get("num") or 0))
    table = Table(title=f"sweep: {len(rows)} job(s)")
    for col in ("job", "status", "run_dir", "detail"):
        table.add_column(col, overflow="fold")
    for r in rows:
        status = "[green]ok[/]" if r["status"] == "ok" else "[bold red]failed[/]"
        # as text, not markup: an install hint keeps its `[tensorboard]`, an override its brackets
        table.add_row(Text(r["job"]), status, Text(r["run_dir"]), Text(r["detail"]))
    Console(stderr=True).print(table)
    return sum(r["status"] != "ok" for r in rows)


def sweep_jobs(overrides: list[str]) -> list[list[str]]:
    """The override lists of every job of a Hydra basic sweep (``seed=0,1 demos=a,b`` -> 4 jobs)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    axes = [[f"{o.get_key_element()}={v}" for v in o.sweep_string_iterator()] if o.is_sweep_override()
            else [o.input_line] for o in OverridesParser.create().parse_overrides(overrides)]
    return [list(job) for job in itertools.product(*axes)]


def run_batched(overrides: list[str]) -> None:
    """``batched=true``: every job of the sweep trained in this process as one ensemble
    (:func:`surrol_data.algos.train_batched.train_batched`), each in its own run_dir."""
    from hydra import compose, initialize_config_dir

    from surrol_data.algos.train_batched import train_batched
    from surrol_data.datasets.reader import DatasetError

    overrides = [o for o in overrides if o not in ("-m", "--multirun")]
    if any(o.startswith("-") for o in overrides):
        raise SystemExit(f"error: batched=true takes config overrides only, not {[o for o in overrides if o[0] == '-']}")
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfgs = [compose("config", overrides=job) for job in sweep_jobs(overrides)]
    try:
        runs = train_batched([to_train_config(c) for c in cfgs], overlap=bool(cfgs[0].batched_overlap),
                             n_workers=int(cfgs[0].experiment.n_envs), progress=bool(cfgs[0].progress))
    except (FileNotFoundError, ValueError, DatasetError) as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    for cfg, rows in zip(cfgs, runs):
        print(f"{cfg.run_dir}: final success {rows[-1]['success_rate']:.2f}")


def main(argv: list[str] | None = None) -> None:
    """Run the Hydra app on ``argv`` (Hydra overrides and flags such as ``-m``, ``--cfg job``).

    A sweep (``-m``) runs every job even when some fail, then prints one table of all jobs and exits 1 if any
    failed. ``batched=true`` trains every job of the sweep in this process as one ensemble instead. A single run
    ends by printing where its outputs are; Ctrl-C ends with the command that resumes (exit status 130).
    """
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        with _quiet_workers_after_ctrl_c():
            _main(args, argv)
    except BaseException as e:  # noqa: BLE001  (only Ctrl-C is handled; everything else goes on up)
        if not _from_interrupt(e):
            raise
        # every finished epoch is checkpointed: say how to go on, not where Python was
        signum = _stopped_by[0] if _stopped_by else signal.SIGINT
        how = "interrupted" if signum == signal.SIGINT else f"stopped by {signal.Signals(signum).name}"
        print(f"{how}; the finished epochs are saved. Resume with: {resume_command(args)}", file=sys.stderr)
        raise SystemExit(128 + signum) from None


def _main(args: list[str], argv: list[str] | None) -> None:
    if "batched=true" in args:
        run_batched([a for a in args if a != "batched=true"])
        return
    if argv is not None:
        sys.argv = ["surrol-data train", *argv]
    cluster = _cluster_launcher(args)
    # The jobs append their lines to one file: on a cluster it must be on the file system the compute nodes share
    # with this one, so it goes in the launch folder (where run_dir is relative to) rather than in /tmp.
    with tempfile.TemporaryDirectory(prefix=".surrol_sweep_", dir=os.getcwd() if cluster else None) as tmp:
        report = Path(tmp) / "jobs.jsonl"
        os.environ[SWEEP_REPORT_VAR] = str(report)  # inherited by the launcher's workers and by sbatch's jobs
        try:
            hydra.main(config_path=str(config_dir()), config_name="config", version_base="1.3")(_run)()
        finally:
            os.environ.pop(SWEEP_REPORT_VAR, None)
            failed = _print_sweep_report(report, _expected_jobs(args), cluster)
    if failed:
        raise SystemExit(1)


def _cluster_launcher(args: list[str]) -> bool:
    """Whether the sweep's jobs run on other machines (a launcher other than the local joblib one)."""
    launchers = [a.split("=", 1)[1] for a in args if a.lstrip("+").startswith("hydra/launcher=")]
    return bool(launchers) and launchers[-1] not in ("local", "joblib", "basic")


def _expected_jobs(args: list[str]) -> list[str]:
    """Each job's label (its overrides, as the job reports it) in job-number order; [] unless a sweep (-m)."""
    if not ({"-m", "--multirun"} & set(args)):
        return []
    overrides = [a for a in args if not a.startswith("-")]
    task = [o for o in overrides if not o.lstrip("+~").startswith(("hydra.", "hydra/"))]
    try:
        return [" ".join(job) or "(defaults)" for job in sweep_jobs(task)]
    except Exception:  # noqa: BLE001  (an override Hydra itself rejects: Hydra has said why already)
        return []


if __name__ == "__main__":
    main()

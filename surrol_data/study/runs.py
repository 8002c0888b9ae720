"""The study run by run: train the next pending runs, commit-ready run folders, the report from what is done.

A run (one demo source, one seed) is the unit: it trains in ``OUT/.work/<source>/seed<k>`` (checkpoints, resumable
after a kill with the same command), and when it finishes its small, final record is moved into
``OUT/runs/<source>/seed<k>/`` in one rename:

* ``metrics.csv`` / ``metrics.jsonl``: the per-epoch evaluation (success, steps to complete, economy of motion,
  losses, timings);
* ``eval_episodes.csv``: one row per per-epoch evaluation episode at the report epochs (success, steps, path,
  failed grasps, attempts, retries, the attempt outcome);
* ``report_episodes.csv``: the report epochs' actors on fresh episodes and under the induced-failure probe
  (:mod:`surrol_data.study.report_eval`): what the report's tables at those epochs stand on;
* ``actors/epochNNN.pt``: the actor at epochs 25, 50, 75, 100 and the report epochs (``surrol-data eval
  --policy`` runs each);
* ``config.yaml`` (the composed Hydra config) and ``config.json`` (the training config the report reads);
* ``run.json``: the code identity (commit, CPU, env / learner / config fingerprints), package versions, the demo
  set's content hash, CPU and wall time;
* ``policy.pt``: the final actor (``surrol-data eval --policy`` runs it).

A finished run's folder is all the report needs; the report is rebuilt from whatever runs are there and says
which of the study's runs it stands on.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import time
from collections.abc import Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path

from surrol_data.evaluation.code_identity import (CodeIdentity, append_check, check_same_code, read_checks)
from surrol_data.study.demo_sets import (build_demo_sets, build_shipped_demo_sets, check_shipped, demo_quality,
                                         demo_quality_markdown, set_paths, tree_hash)
from surrol_data.study.identity import current_identity, repo_root
from surrol_data.study.spec import StudySpec, load_spec, parse_runs, run_name

RUN_RECORD = "run.json"
CHECKS_FILE = "code_checks.jsonl"
KEPT = ("metrics.csv", "metrics.jsonl", "eval_episodes.csv", "report_episodes.csv", "policy.pt", "actors")
# The paper's figure of a retry is of policies at epoch 50: the report draws it when 50 is a report epoch.
RETRY_FRAMES_EPOCH = 50


def run_folder(out: Path, source: str, seed: int) -> Path:
    return out / "runs" / source / f"seed{seed}"


def work_folder(out: Path, source: str, seed: int) -> Path:
    """Where a run trains (checkpoints) until it is finished."""
    return out / ".work" / source / f"seed{seed}"


def finished_runs(out: Path, spec: StudySpec) -> list[tuple[str, int]]:
    return [r for r in spec.run_order() if (run_folder(out, *r) / RUN_RECORD).is_file()]


def committed_identities(out: Path, spec: StudySpec) -> dict[str, CodeIdentity]:
    found = {}
    for source, seed in finished_runs(out, spec):
        record = json.loads((run_folder(out, source, seed) / RUN_RECORD).read_text())
        found[f"run {run_name(source, seed)}"] = CodeIdentity.from_dict(record["code"])
    return found


def _demo_root(spec: StudySpec, out: Path) -> Path | None:
    shipped = spec.shipped_demo_dir()
    if shipped is None:
        return None
    path = Path(shipped)
    return path if path.is_absolute() else repo_root() / path


def prepare_demo_sets(spec: StudySpec, out: Path, *, build: bool, progress: bool) -> tuple[dict[str, Path], dict]:
    """The study's demo sets (source -> dataset) and their hashes (dataset name -> sha256): the shipped ones,
    checked against their manifest (built first with ``build``), or OUT/demos built here for a study without."""
    root = _demo_root(spec, out)
    if root is None:
        sets = build_demo_sets(out / "demos", spec, progress=progress)
        return sets, {p.name: tree_hash(p) for p in dict.fromkeys(sets.values())}
    if build:
        build_shipped_demo_sets(root, spec, progress=progress)
    return set_paths(root, spec), check_shipped(root, spec)


def _compose(spec: StudySpec, experiment: str, out: Path, sets: dict[str, Path], runs, progress: bool) -> list:
    from hydra import compose, initialize_config_dir

    from surrol_data.train_app import config_dir

    given = {o.split("=", 1)[0].lstrip("+~") for o in (*spec.run_overrides, *spec.overrides)}
    cfgs = []
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        for source, seed in runs:
            base = [f"algo={spec.algo}", f"task={spec.task}", f"experiment={experiment}", f"demos={source}",
                    f"demos.path={sets[source]}", f"demos.num={spec.episodes}", f"seed={seed}",
                    f"run_dir={work_folder(out, source, seed)}", "resume=true", "tensorboard=false",
                    f"progress={str(progress).lower()}"]
            base = [o for o in base if o.split("=", 1)[0] not in given]   # the config's and the user's win
            cfgs.append(compose("config", overrides=[*base, *spec.run_overrides, *spec.overrides]))
    return cfgs


def _last_epoch(work: Path) -> int | None:
    from surrol_data.algos.train import read_metrics

    if not (work / "checkpoint.pt").is_file() or not (work / "metrics.jsonl").is_file():
        return None
    rows = read_metrics(work)
    return int(rows[-1]["epoch"]) if rows else None


def _start_batch(out: Path, names: list[str], shared: bool = True) -> None:
    """Before training ``names`` as one batch. A kill leaves a batch's checkpoints: the same batch again resumes
    them. A batch of other runs resumes those of its runs that all have checkpoints (every member's checkpoint is
    a single run's, so an ensemble can resume a subset of an earlier one: e.g. a batch split so that some of its
    runs finish sooner); otherwise its runs start afresh. Each run's ``batches.json`` records from which epoch it
    trained in a batch of how many runs (its CPU time is its share of each batch's). ``shared=False``: a run
    trained on its own beside others (a cluster job), which neither reads nor writes the one ``.work/batch.json``
    that a local batch keeps."""
    work = out / ".work"
    record = work / "batch.json"
    before = json.loads(record.read_text()) if shared and record.is_file() else []
    folders = [work_folder(out, source, int(seed)) for source, seed in (name.split("/") for name in names)]
    last = {folder: _last_epoch(folder) for folder in folders}
    resumable = before == names or all(epoch is not None for epoch in last.values())
    for folder in folders:
        if not resumable:
            shutil.rmtree(folder, ignore_errors=True)
            last[folder] = None
        history_path = folder / "batches.json"
        history = json.loads(history_path.read_text()) if resumable and history_path.is_file() else []
        if not history and before and last[folder] is not None:
            history = [{"from_epoch": 0, "members": len(before)}]   # trained before batches were recorded
        start = last[folder] + 1 if last[folder] is not None else 0
        if not history or history[-1]["members"] != len(names):
            history.append({"from_epoch": start, "members": len(names)})
        folder.mkdir(parents=True, exist_ok=True)
        history_path.write_text(json.dumps(history))
    if shared:
        record.write_text(json.dumps(names))


def _end_batch(out: Path) -> None:
    """After a batch finished: its runs' work folders are gone (moved into runs/); other runs' checkpoints (of an
    earlier, split batch) stay to be resumed."""
    work = out / ".work"
    (work / "batch.json").unlink(missing_ok=True)
    for folder in sorted(work.glob("*/*"), reverse=True) + sorted(work.glob("*"), reverse=True) + [work]:
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


def _cpu_share(rows: list[dict], history: list[dict]) -> float:
    """The run's share of its batches' CPU seconds: each epoch's ensemble CPU over that epoch's batch size."""
    def members(epoch: int) -> int:
        return next((h["members"] for h in reversed(history) if h["from_epoch"] <= epoch), history[0]["members"])

    return sum((r.get("time_cpu_learner_s", 0.0) + r.get("time_cpu_envs_s", 0.0))
               / r.get("batched_members", members(int(r["epoch"]))) for r in rows)


def _finish_run(out: Path, spec: StudySpec, source: str, seed: int, work: Path, composed, identity: CodeIdentity,
                demo_hash: dict, started: float, members: int) -> Path:
    """Move a trained run's record into ``OUT/runs/<source>/seed<k>`` (one rename) and drop its checkpoints."""
    from omegaconf import OmegaConf

    from surrol_data.algos.train import read_metrics
    from surrol_data.evaluation.study_report import versions

    final = run_folder(out, source, seed)
    tmp = final.with_name(f".{final.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in KEPT:
        if (work / name).is_dir():
            shutil.copytree(work / name, tmp / name)
        elif (work / name).exists():
            shutil.copy2(work / name, tmp / name)
    config = json.loads((work / "config.json").read_text())
    config["run_dir"] = final.relative_to(out).as_posix()
    (tmp / "config.json").write_text(json.dumps(config, indent=2))
    (tmp / "config.yaml").write_text(OmegaConf.to_yaml(composed, resolve=True))
    rows = read_metrics(work)
    history = json.loads((work / "batches.json").read_text()) if (work / "batches.json").is_file() else \
        [{"from_epoch": 0, "members": members}]
    cpu = _cpu_share(rows, history)
    dataset = Path(config["demos"]["path"]).name
    record = {
        "study": spec.experiment, "source": source, "seed": seed, "task": spec.task, "algo": spec.algo,
        "epochs": max(int(r["epoch"]) for r in rows), "code": identity.as_dict(), "versions": versions(),
        "demos": {"dataset": dataset, "sha256": demo_hash[dataset], "episodes": len(config.get("demo_episodes", []))},
        "time": {"wall_s": round(rows[-1]["wall_s"], 1), "cpu_s": round(cpu, 1), "batched_members": members,
                 "batches": history,
                 "started": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(started)),
                 "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")},
        "machine": {"cpu": identity.cpu, "cores": os.cpu_count()},
    }
    (tmp / RUN_RECORD).write_text(json.dumps(record, indent=2) + "\n")
    if final.exists():   # a folder without run.json: an unfinished earlier attempt
        shutil.rmtree(final)
    os.replace(tmp, final)
    shutil.rmtree(work, ignore_errors=True)
    return final


def run_study(experiment: str, out: str | Path, *, natural: bool = False, overrides: Sequence[str] = (),
              next_runs: int | None = None, runs: str | None = None, train: bool = True, build_demos: bool = False,
              check_code: bool = False, progress: bool = True,
              say=print) -> dict[str, Path]:
    """Train the selected runs of the study (``runs`` by name, else the next ``next_runs`` pending, else all
    pending; none with ``train=False``), then rebuild the report from every finished run. Returns the report's
    files (see :func:`surrol_data.evaluation.study_report.write_study_report`)."""
    spec = study_spec(experiment, overrides, natural)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    sets, hashes = prepare_demo_sets(spec, out, build=build_demos, progress=progress)
    demo_md = demo_quality_markdown(demo_quality(sets, spec.task), spec.matched, spec.task)
    (out / "demos.md").write_text(f"# Demonstrations\n\n{demo_md}")

    done = finished_runs(out, spec)
    selected = select_runs(out, spec, runs=runs, next_runs=next_runs) if train else []
    if selected or check_code:
        cfgs, train_cfgs, identity = _checked_configs(spec, experiment, out, sets, selected or spec.run_order()[:1],
                                                      progress)
        if check_code:   # recorded only once it passed: the ledger links code that means the same
            append_check(out / CHECKS_FILE, identity)
            say(f"this checkout means the same code as the {len(done)} finished run(s); recorded its identity in "
                f"{out / CHECKS_FILE}: {identity.short()}")
    if selected:
        names = [run_name(*r) for r in selected]
        say(f"training {len(selected)} run(s) of {experiment} as one batch: {', '.join(names)} "
            f"({len(done)} of {len(spec.run_order())} finished before)")
        folders = _train_batch(out, spec, selected, cfgs, train_cfgs, identity, hashes, progress)
        for run, folder in zip(selected, folders):
            say(f"finished {run_name(*run)}: {folder}")
        _end_batch(out)
    return study_report(experiment, out, spec, demo_md, natural)


def study_spec(experiment: str, overrides: Sequence[str] = (), natural: bool = False) -> StudySpec:
    spec = load_spec(experiment, overrides)
    return replace(spec, matched=False) if natural else spec


def select_runs(out: Path, spec: StudySpec, *, runs: str | None = None, next_runs: int | None = None) -> list:
    """The runs to train: ``runs`` by name (none of them finished), else the next ``next_runs`` pending, else all
    pending."""
    done = finished_runs(out, spec)
    if runs:
        selected = parse_runs(runs, spec)
        already = [run_name(*r) for r in selected if r in done]
        if already:
            raise ValueError(f"run(s) {', '.join(already)} are finished already (in {out / 'runs'}); to redo one, "
                             "delete its folder first")
        return selected
    pending = [r for r in spec.run_order() if r not in done]
    return pending if next_runs is None else pending[:next_runs]


def _checked_configs(spec: StudySpec, experiment: str, out: Path, sets: dict[str, Path], runs, progress: bool):
    """The runs' composed and training configs and this checkout's code identity, checked against the finished
    runs' and the recorded checks (:func:`check_same_code`)."""
    from surrol_data.train_app import to_train_config

    cfgs = _compose(spec, experiment, out, sets, runs, progress)
    train_cfgs = [to_train_config(c) for c in cfgs]
    identity = current_identity(train_cfgs[0])
    check_same_code({**committed_identities(out, spec), "this checkout": identity}, read_checks(out / CHECKS_FILE))
    return cfgs, train_cfgs, identity


def _train_batch(out: Path, spec: StudySpec, selected, cfgs, train_cfgs, identity, hashes, progress: bool,
                 shared: bool = True) -> list[Path]:
    """Train ``selected`` as one batched ensemble and move each into its run folder (see :func:`_start_batch`)."""
    from surrol_data.algos.train_batched import train_batched
    from surrol_data.study.report_eval import (actor_epochs, evaluate_report_epochs, evaluated_epochs,
                                               has_report_episodes)

    _start_batch(out, [run_name(*r) for r in selected], shared=shared)
    started = time.time()
    schedule = train_cfgs[0].schedule
    train_batched(train_cfgs, overlap=bool(cfgs[0].batched_overlap), n_workers=int(schedule.n_envs),
                  progress=progress, episode_epochs=tuple(spec.report_epochs),
                  actor_epochs=actor_epochs(spec.report_epochs, schedule.epochs))
    evaluated = evaluated_epochs(spec.report_epochs, schedule.epochs)
    for (source, seed), cfg in zip(selected, train_cfgs):
        if has_report_episodes(cfg.run_dir, evaluated, spec.report_episodes):
            continue   # (a study killed after this run's report evaluation, resumed)
        if progress:
            print(f"evaluating {run_name(source, seed)} at epochs {list(evaluated)}: "
                  f"{spec.report_episodes} fresh and {spec.report_episodes} probed episodes each")
        evaluate_report_epochs(cfg.run_dir, cfg.env_id, evaluated, spec.report_episodes,
                               schedule.max_episode_steps)
    return [_finish_run(out, spec, source, seed, Path(cfg.run_dir), composed, identity, hashes, started,
                        len(selected))
            for (source, seed), cfg, composed in zip(selected, train_cfgs, cfgs)]


def train_one_run(experiment: str, out: str | Path, source: str, seed: int, *, natural: bool = False,
                  overrides: Sequence[str] = ()) -> Path:
    """One run of the study trained on its own, beside others (a cluster job of ``study --launcher slurm``): the
    same configs, code check, training (a batch of one) and run folder as a local batch gives its members. A run
    with checkpoints resumes (a requeued or resubmitted job); a finished one is left as it is."""
    spec = study_spec(experiment, overrides, natural)
    out = Path(out).resolve()
    final = run_folder(out, source, seed)
    if (final / RUN_RECORD).is_file():
        return final
    sets, hashes = prepare_demo_sets(spec, out, build=False, progress=False)
    cfgs, train_cfgs, identity = _checked_configs(spec, experiment, out, sets, [(source, seed)], False)
    return _train_batch(out, spec, [(source, seed)], cfgs, train_cfgs, identity, hashes, False, shared=False)[0]


def study_report(experiment: str, out: Path, spec: StudySpec, demo_md: str, natural: bool = False) -> dict:
    """The report from every finished run (nothing when none is)."""
    from surrol_data.evaluation.study_report import write_study_report

    if not finished_runs(out, spec):
        return {}
    from surrol_data.study.report_eval import RECOVERY_EPOCHS
    from surrol_data.study.retry_figure import retry_frames_section

    return write_study_report([out / "runs"], out, epochs=list(spec.report_epochs), demo_table_markdown=demo_md,
                              recovery_epochs=sorted({*spec.report_epochs, *RECOVERY_EPOCHS}),
                              notes=_notes(spec, experiment),
                              expected_runs=[run_name(*r) for r in spec.run_order()],
                              code_checks=read_checks(out / CHECKS_FILE),
                              command=_rebuild_command(experiment, out, natural),
                              figures=(partial(retry_frames_section, epoch=RETRY_FRAMES_EPOCH)
                                       if RETRY_FRAMES_EPOCH in spec.report_epochs else None))


def _rebuild_command(experiment: str, out: Path, natural: bool) -> str:
    """The command that rebuilds this report from the committed runs. Not the command that happened to run last
    (a training batch or a code check would name its own options and this machine's absolute paths). The path is
    relative to the repository that holds the report (a batch may run from another worktree)."""
    out = Path(out).resolve()
    root = next((p for p in out.parents if (p / ".git").exists()), Path.cwd().resolve())
    try:
        shown = out.relative_to(root)
    except ValueError:
        shown = out
    return shlex.join(["surrol-data", "study", experiment, "--out", str(shown), *(["--natural"] if natural else []),
                       "--report"])


def _notes(spec: StudySpec, experiment: str) -> str:
    natural_note = ("" if spec.matched else "\n\nThese runs use the **natural** demo sets (not matched to the paper's "
                    "demo lengths), so the comparison mixes skill with demo length.")
    return (f"Experiment `{experiment}`: {spec.task}, algo `{spec.algo}`, {len(spec.seeds)} seeds × "
            f"{len(spec.sources)} demo sources, {spec.episodes} demos per source ({spec.operators} simulated "
            f"operators × {spec.episodes // spec.operators} per skill), demo horizon {spec.horizon} steps. "
            "The paper's human demos came from people at a dVRK console; ours come from simulated operators "
            "driving the same device mapping, calibrated to the paper's demo lengths where matched."
            + natural_note)

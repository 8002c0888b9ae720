"""Demos or interventions (issue 31): success against frames of human effort, as whole demos or as takeovers.

    surrol-data interventions --out docs/results/interventions            # run (or continue) and report
    surrol-data interventions --out OUT --override experiment.interventions.seeds=[0]   # any key of the block

For each task and seed (``configs/experiment/interventions.yaml``, block ``interventions:``):

1. the simulated operator records ``base_demos`` whole demonstrations; BC on them is the weak policy (round 0);
2. **interventions** (HG-DAgger): in each of K rounds the operator supervises ``rollouts_per_round`` rollouts of the
   latest policy (``collect --source intervene``, the supervisor of :mod:`surrol_data.collect.operator.supervisor`);
   BC is retrained on the demos and every takeover segment so far (:data:`~surrol_data.algos.demos.DemoSpec`
   ``frames``);
3. **demos**: the same operator instead records more whole demos, until they hold as many frames as the
   interventions' operator drove; BC on those;
4. every policy is evaluated on the same fixed seeds; the report plots success against the frames a person drove
   (mean over seeds, bootstrap 95 % interval) and tabulates it per round.

Human effort is counted in frames the operator drove: a whole demo's every frame, an intervention's takeover frames.
The time a person spends watching the policy act is not counted (it is reported beside, as supervised frames).

Every finished step is recorded in ``OUT/results.jsonl`` (one line per policy evaluated) and its datasets and policies
stay in ``OUT/work``, so an interrupted run continues where it stopped; the report is rebuilt from the lines.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from surrol_data.study.spec import experiment_block

RESULTS = "results.jsonl"
ARMS = ("interventions", "demos")
ARM_COLOURS = {"interventions": "#c44e52", "demos": "#4c72b0"}
DEMO_SEED_STRIDE = 100_000    # seed k's episodes start at k·stride: no two seeds share a scene
ROUND_SEED_STRIDE = 10_000    # round r's supervised rollouts start r·stride after the seed's demos


@dataclass(frozen=True)
class InterventionSpec:
    """The ``interventions:`` block of an experiment config (see ``configs/experiment/interventions.yaml``)."""
    experiment: str
    tasks: tuple[str, ...] = ("NeedlePick", "GauzeRetrieve")
    seeds: tuple[int, ...] = (0, 1, 2)
    base_demos: int = 10
    rounds: int = 3
    rollouts_per_round: int = 10
    skill: str = "expert"
    frames: str = "human"
    eval_episodes: int = 20
    bc_epochs: int = 10
    bc_steps_per_epoch: int = 100
    bc_gmm_modes: int = 0
    overrides: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self):
        from surrol_data.algos.demos import FRAME_SELECTIONS

        if min(self.base_demos, self.rollouts_per_round, self.eval_episodes, self.bc_epochs,
               self.bc_steps_per_epoch, len(self.seeds), len(self.tasks)) < 1 or min(self.rounds, self.bc_gmm_modes) < 0:
            raise ValueError(f"interventions: base_demos, rollouts_per_round, eval_episodes, bc_epochs, "
                             f"bc_steps_per_epoch must be >= 1, rounds and bc_gmm_modes >= 0, and tasks and seeds not "
                             f"empty: {self}")
        if self.frames not in FRAME_SELECTIONS[1:]:
            raise ValueError(f"interventions.frames must be one of {FRAME_SELECTIONS[1:]}, got {self.frames!r}")
        if self.skill not in ("expert", "novice"):
            raise ValueError(f"interventions.skill must be expert or novice, got {self.skill!r}")

    @property
    def operator_id(self) -> str:
        return f"{self.skill}1"


def _as_tuples(values: dict) -> dict:
    """``tasks`` and ``seeds`` as the spec holds them (tuples), from a config block or ``spec.json`` (lists)."""
    return {k: tuple(v) if k in ("tasks", "seeds") else v for k, v in values.items()}


def load_intervention_spec(experiment: str = "interventions", overrides: Sequence[str] = ()) -> InterventionSpec:
    values = _as_tuples(experiment_block(experiment, "interventions", overrides, "experiment=interventions"))
    unknown = set(values) - set(InterventionSpec.__dataclass_fields__)
    if unknown:
        raise ValueError(f"interventions: unknown key(s) {sorted(unknown)}; known: "
                         f"{sorted(set(InterventionSpec.__dataclass_fields__) - {'experiment', 'overrides'})}")
    return InterventionSpec(experiment=experiment, overrides=tuple(overrides), **values)


# ---- one (task, seed): the two arms, round by round ----------------------------------------------------------------

class _Cell:
    """One task and seed: its datasets and policies under ``OUT/work/<task>/seed<k>``."""

    def __init__(self, out: Path, spec: InterventionSpec, task: str, seed: int, done: dict, progress: bool, say):
        self.out, self.spec, self.task, self.seed, self.done, self.progress, self.say = \
            out, spec, task, seed, done, progress, say
        self.work = out / "work" / task / f"seed{seed}"
        self.demos = self.work / "demos"
        self.clock = time.process_time()    # CPU seconds since the last row: what each step of the arm cost

    # data

    def _record(self, dataset: Path, episodes: int, seed: int | None, policy=None, policy_info=None) -> None:
        from surrol_data.collect.haptic_source import collect_haptic

        append = dataset.exists()
        collect_haptic(self.task, episodes, dataset, device="operator", operator_id=self.spec.operator_id,
                       skill=self.spec.skill, seed=None if append else seed, append=append, progress=False,
                       policy=policy, policy_info=policy_info, keep_failures=policy is not None,
                       max_attempts=episodes if policy is not None else 10 * episodes,
                       command=f"surrol-data interventions ({self.spec.experiment})")

    def _episodes(self, dataset: Path) -> int:
        from surrol_data.datasets.reader import DatasetReader

        return len(DatasetReader(dataset).episodes) if (dataset / "meta" / "info.json").exists() else 0

    def demo_trajectories(self, count: int) -> list:
        """The first ``count`` whole demos (recorded here first when fewer exist)."""
        from surrol_data.algos.demos import DemoSpec, load_demos

        have = self._episodes(self.demos)
        if have < count:
            self._record(self.demos, count - have, self.seed * DEMO_SEED_STRIDE)
        return load_demos(DemoSpec(path=str(self.demos), num=count), None)[0]

    def demos_for_frames(self, frames: int) -> list:
        """The fewest whole demos (at least ``base_demos``) holding at least ``frames`` frames."""
        count = self.spec.base_demos
        while True:
            trajs = self.demo_trajectories(count)
            total = sum(len(t) for t in trajs)
            if total >= frames:
                return trajs
            mean = total / len(trajs)
            count += max(1, int(np.ceil((frames - total) / mean)))

    def supervised(self, round_: int, policy_path: Path) -> list:
        """Round ``round_``'s supervised rollouts of the policy at ``policy_path`` (recorded here when missing)."""
        from surrol_data.algos.demos import DemoSpec, load_demos
        from surrol_data.algos.policies import describe_policy, load_policy

        dataset = self.work / f"round{round_}"
        if self._episodes(dataset) < self.spec.rollouts_per_round:
            shutil.rmtree(dataset, ignore_errors=True)   # cut short: its seeds are fixed, so record it anew
            self._record(dataset, self.spec.rollouts_per_round,
                         self.seed * DEMO_SEED_STRIDE + round_ * ROUND_SEED_STRIDE,
                         policy=load_policy(policy_path), policy_info=describe_policy(policy_path))
        return load_demos(DemoSpec(path=str(dataset), num=self.spec.rollouts_per_round, successful_only=False),
                          None)[0]

    # learning and scoring

    def train(self, name: str, trajectories: list, frames: str = "all") -> Path:
        from surrol_data.algos.bc import BCConfig, demo_arrays, train_bc
        from surrol_data.algos.demos import select_frames

        path = self.work / f"{name}.pt"
        if not path.is_file():
            kept, _ = select_frames(trajectories, list(range(len(trajectories))), frames)
            obs, goal, action, episode = demo_arrays(kept)
            config = BCConfig(epochs=self.spec.bc_epochs, steps_per_epoch=self.spec.bc_steps_per_epoch,
                              seed=self.seed, gmm_modes=self.spec.bc_gmm_modes)
            policy = train_bc(obs, goal, action, config, episode_index=episode, progress=False)
            tmp = policy.save(path.with_suffix(".partial"))
            tmp.replace(path)
        return path

    def evaluate(self, policy_path: Path) -> dict:
        from surrol_data.algos.policies import load_policy
        from surrol_data.collect.haptic_source import human_horizon
        from surrol_data.envs import env_id
        from surrol_data.evaluation.rollout import evaluate

        # The horizon of the supervised rollouts: success means the same in both.
        result = evaluate(env_id(self.task), load_policy(policy_path), self.spec.eval_episodes,
                          max_steps=human_horizon(self.task), progress=False)
        return {"success": float(result.summary["success_rate"])}

    def row(self, arm: str, round_: int, policy_path: Path, human_frames: int, **extra) -> dict:
        key = (self.task, self.seed, arm, round_)
        if key in self.done:
            return self.done[key]
        started = time.process_time()
        row = {"task": self.task, "seed": self.seed, "arm": arm, "round": round_, "human_frames": int(human_frames),
               **extra, **self.evaluate(policy_path)}
        now = time.process_time()
        row["eval_cpu_s"], row["cpu_s"] = round(now - started, 2), round(now - self.clock, 2)
        self.clock = now
        with open(self.out / RESULTS, "a") as f:
            f.write(json.dumps(row) + "\n")
        self.done[key] = row
        self.say(f"{self.task} seed {self.seed} {arm} round {round_}: {human_frames} human frames, "
                 f"success {row['success']:.2f}")
        return row

    def run(self) -> None:
        from surrol_data.datasets.interventions import trajectory_interventions

        self.work.mkdir(parents=True, exist_ok=True)
        base = self.demo_trajectories(self.spec.base_demos)
        base_frames = sum(len(t) for t in base)
        policy = self.train("round0", base)
        for arm in ARMS:
            self.row(arm, 0, policy, base_frames, demos=len(base), supervised_frames=0)
        takeovers: list = []
        supervised = 0
        for r in range(1, self.spec.rounds + 1):
            rollouts = self.supervised(r, policy)
            supervised += sum(len(t) for t in rollouts)
            takeovers += rollouts
            intervention_frames = sum(trajectory_interventions(t).intervention_frames for t in takeovers)
            policy = self.train(f"interventions_round{r}", base + takeovers, self.spec.frames)
            self.row("interventions", r, policy, base_frames + intervention_frames, demos=len(base),
                     supervised_frames=supervised)
            demos = self.demos_for_frames(base_frames + intervention_frames)
            demo_policy = self.train(f"demos_round{r}_{len(demos)}", demos)
            self.row("demos", r, demo_policy, sum(len(t) for t in demos), demos=len(demos), supervised_frames=0)


# ---- the whole experiment and its report --------------------------------------------------------------------------

def recorded_spec(out: str | Path) -> InterventionSpec:
    """The configuration the run in ``out`` recorded (``spec.json``, written by :func:`run_interventions`)."""
    return InterventionSpec(**_as_tuples(json.loads((Path(out) / "spec.json").read_text())))


def read_results(out: Path) -> list[dict]:
    path = Path(out) / RESULTS
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def run_interventions(out: str | Path, experiment: str = "interventions", overrides: Sequence[str] = (), *,
                      train: bool = True, progress: bool = True, say=print, workers: int = 1) -> dict[str, Path]:
    """Run (or continue) the experiment in ``out`` and write its report; returns the report's files. ``workers``
    > 1 runs that many (task, seed) cells at once in separate processes: the same rows, sooner."""
    spec = load_intervention_spec(experiment, overrides)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    recorded = out / "spec.json"
    mine = {k: v for k, v in asdict(spec).items() if k != "overrides"}
    if recorded.is_file() and read_results(out):
        before = json.loads(recorded.read_text())
        if before != json.loads(json.dumps(mine)):
            raise ValueError(f"{out} holds results of another configuration ({recorded}); use a new --out folder or "
                             "the same overrides")
    recorded.write_text(json.dumps(mine, indent=2) + "\n")
    if train:
        done = {(r["task"], r["seed"], r["arm"], r["round"]): r for r in read_results(out)}
        cells = [(task, seed) for seed in spec.seeds for task in spec.tasks]
        from tqdm.auto import tqdm

        bar = tqdm(total=len(cells), desc="interventions", disable=not progress)
        if workers <= 1:
            for task, seed in cells:
                _Cell(out, spec, task, seed, done, progress, say).run()
                bar.update(1)
        else:
            _run_cells_in_parallel(out, spec, cells, done, workers, bar, say)
        bar.close()
    return write_interventions_report(out, spec)


def _run_cell(out: Path, spec: InterventionSpec, task: str, seed: int, done: dict) -> None:
    """One cell in a worker process (module level, so a process pool can pickle it)."""
    _Cell(out, spec, task, seed, done, False, print).run()


def _run_cells_in_parallel(out: Path, spec: InterventionSpec, cells: list, done: dict, workers: int, bar,
                           say) -> None:
    """The cells in ``workers`` processes. Cells share nothing but ``results.jsonl``, to which each appends whole
    lines (one write each, so lines never interleave); a cell's rows do not depend on which process ran it."""
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from surrol_data.collect.parallel_rollouts import exit_with

    # spawn: the workers start clean (no PyBullet client or torch threads inherited from this process); exit_with: a
    # killed run leaves no worker appending to results.jsonl beside the run that resumes it
    with ProcessPoolExecutor(max_workers=min(workers, len(cells)), mp_context=multiprocessing.get_context("spawn"),
                             initializer=exit_with, initargs=(os.getpid(),)) as pool:
        futures = {pool.submit(_run_cell, out, spec, task, seed, done): (task, seed) for task, seed in cells}
        for future in as_completed(futures):
            future.result()     # a failed cell fails the run (finished rows stay in results.jsonl)
            task, seed = futures[future]
            say(f"{task} seed {seed}: done")
            bar.update(1)


def summary_rows(rows: Sequence[dict], spec: InterventionSpec) -> list[dict]:
    """Per task, arm and round: mean human frames and the success estimate over seeds (bootstrap 95 % interval)."""
    from surrol_data.datasets.metrics import estimate

    table = []
    for task in spec.tasks:
        for r in range(spec.rounds + 1):
            for arm in ARMS:
                group = [x for x in rows if x["task"] == task and x["arm"] == arm and x["round"] == r]
                if not group:
                    continue
                table.append({"task": task, "arm": arm, "round": r, "seeds": len(group),
                              "human_frames": float(np.mean([x["human_frames"] for x in group])),
                              "supervised_frames": float(np.mean([x.get("supervised_frames", 0) for x in group])),
                              "demos": float(np.mean([x["demos"] for x in group])),
                              "success": estimate([x["success"] for x in group])})
    return table


def _markdown(table: list[dict], spec: InterventionSpec, figure: str, rows: Sequence[dict]) -> str:
    def pct(e) -> str:
        if e.n == 0:
            return "–"
        ci = "" if not np.isfinite(e.ci_low) else f" [{100 * e.ci_low:.0f}, {100 * e.ci_high:.0f}]"
        return f"{100 * e.mean:.0f}{ci}"

    learner = (f"BC-GMM ({spec.bc_gmm_modes} modes)" if spec.bc_gmm_modes else "BC (MSE)") + \
        f", {spec.bc_epochs * spec.bc_steps_per_epoch} gradient steps from scratch per policy"
    lines = ["# Demos or interventions", "",
             f"Experiment `{spec.experiment}`: BC from {spec.base_demos} whole demos of the simulated {spec.skill} "
             f"operator, then {spec.rounds} rounds of {spec.rollouts_per_round} rollouts that the same operator "
             f"supervises and takes over (HG-DAgger; BC retrained on the demos and the takeover frames, "
             f"`demos.frames={spec.frames}`), against BC on whole demos holding as many frames as the operator drove. "
             f"Success over {spec.eval_episodes} evaluation episodes on fixed seeds, mean over "
             f"{len(spec.seeds)} seeds with a bootstrap 95 % interval (in %). Human frames: the frames the operator "
             "drove (whole demos, takeovers); supervised frames: the frames the operator watched the policy act. "
             f"Learner: {learner}.", "",
             f"![success against human frames]({figure})", ""]
    for task in spec.tasks:
        lines += [f"## {task}", "",
                  "| Round | Interventions: human frames | supervised frames | success (%) | Demos: demos | human frames "
                  "| success (%) |", "|---|---|---|---|---|---|---|"]
        for r in range(spec.rounds + 1):
            cells = {x["arm"]: x for x in table if x["task"] == task and x["round"] == r}
            if not cells:
                continue
            i, d = cells.get("interventions"), cells.get("demos")
            lines.append(f"| {r} | {i['human_frames']:.0f} | {i['supervised_frames']:.0f} | {pct(i['success'])} | "
                         f"{d['demos']:.1f} | {d['human_frames']:.0f} | {pct(d['success'])} |"
                         if i and d else f"| {r} | – | – | – | – | – | – |")
        lines.append("")
    cpu = sum(r.get("cpu_s", 0.0) for r in rows)
    lines += ["## What made these numbers", "",
              f"{len(rows)} evaluated policies in `{RESULTS}` ({cpu / 60:.1f} CPU minutes of recording, training and "
              f"evaluation, {sum(r.get('eval_cpu_s', 0.0) for r in rows) / 60:.1f} of them evaluation); rebuilt with "
              "`surrol-data interventions --out OUT --report`.", ""]
    return "\n".join(lines)


def plot_interventions(path: Path, table: list[dict], spec: InterventionSpec) -> Path:
    import matplotlib

    matplotlib.use("Agg")   # headless
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(spec.tasks), figsize=(5.5 * len(spec.tasks), 4), squeeze=False)
    for ax, task in zip(axes[0], spec.tasks, strict=True):
        for arm in ARMS:
            points = sorted((x for x in table if x["task"] == task and x["arm"] == arm), key=lambda x: x["round"])
            if not points:
                continue
            x = [p["human_frames"] for p in points]
            mean = [100 * p["success"].mean for p in points]
            ax.plot(x, mean, "o-", color=ARM_COLOURS[arm], label=arm)
            low = [100 * (p["success"].ci_low if np.isfinite(p["success"].ci_low) else p["success"].mean) for p in points]
            high = [100 * (p["success"].ci_high if np.isfinite(p["success"].ci_high) else p["success"].mean)
                    for p in points]
            ax.fill_between(x, low, high, color=ARM_COLOURS[arm], alpha=0.2)
        ax.set(title=task, xlabel="frames a person drove", ylabel="success (%)", ylim=(-5, 105))
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_interventions_report(out: Path, spec: InterventionSpec) -> dict[str, Path]:
    """``report.md``, ``report.html`` (self-contained) and ``success_vs_effort.png`` from ``OUT/results.jsonl``;
    nothing when no policy has been evaluated yet."""
    from surrol_data.evaluation.study_report import markdown_to_html

    rows = [r for r in read_results(out) if r["task"] in spec.tasks and r["seed"] in spec.seeds]
    if not rows:
        return {}
    table = summary_rows(rows, spec)
    figure = plot_interventions(out / "success_vs_effort.png", table, spec)
    markdown = _markdown(table, spec, figure.name, rows)
    (out / "report.md").write_text(markdown)
    (out / "report.html").write_text(markdown_to_html(markdown, out, "Demos or interventions"))
    return {"markdown": out / "report.md", "html": out / "report.html", "figure": figure}

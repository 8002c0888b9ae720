"""The main job, end to end on embedded defaults: script demos → LeRobot dataset → BC → evaluation → report.

Everything it makes lands in one folder (by default a new ``outputs/demo-<date>-<time>`` under the folder it runs
in, which the repository's .gitignore leaves out): the dataset (with its card), the BC checkpoint, a Rerun
recording of a demo beside a BC rollout, and ``report.md`` with a table and a plot. It ends by saying where each
is and which commands to try next, in the form that runs in the user's shell (``uv run ...`` under uv).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.table import Table

DEMO_TASK = "NeedlePick"
DEMO_EPISODES = 20
EVAL_EPISODES = 20


@dataclass
class DemoOutputs:
    out: Path
    dataset: Path
    policy: Path
    report: Path
    recording: Path
    summaries: dict


def run_demo(out: str | Path | None = None, episodes: int = DEMO_EPISODES, eval_episodes: int = EVAL_EPISODES,
             seed: int = 0, bc_epochs: int = 20, console: Console | None = None) -> DemoOutputs:
    console = console or Console()
    out = Path(out) if out else default_out()
    out.mkdir(parents=True, exist_ok=True)
    dataset = out / "dataset"
    if dataset.exists():
        raise FileExistsError(f"{dataset} already exists: give the demo an empty or new --out folder")
    t0 = time.perf_counter()

    console.rule(f"[bold]1/4 collect {episodes} scripted {DEMO_TASK} demos")
    from surrol_data.collect.script_source import collect_script

    collect_script(DEMO_TASK, episodes, dataset, seed=seed, command=f"surrol-data demo --out {out}")

    console.rule("[bold]2/4 train behaviour cloning")
    from surrol_data.algos.bc import BCConfig, demo_arrays, train_bc
    from surrol_data.datasets.reader import DatasetReader

    demos = DatasetReader(dataset).trajectories()
    obs, goal, action, episode = demo_arrays(demos)
    policy = train_bc(obs, goal, action, BCConfig(epochs=bc_epochs, seed=seed), episode_index=episode)
    policy_path = policy.save(out / "bc_policy.pt")

    console.rule(f"[bold]3/4 evaluate oracle and BC on {eval_episodes} unseen seeds")
    from surrol_data.envs import env_id
    from surrol_data.evaluation.rollout import EVAL_SEED_BASE as EVAL_SEED
    from surrol_data.evaluation.rollout import ORACLE, evaluate

    oracle = evaluate(env_id(DEMO_TASK), ORACLE, eval_episodes, seed=EVAL_SEED)
    bc = evaluate(env_id(DEMO_TASK), policy, eval_episodes, seed=EVAL_SEED, keep_trajectories=True)

    console.rule("[bold]4/4 report and Rerun recording")
    from surrol_data.evaluation.report import write_report
    from surrol_data.viz.rerun_log import save_rrd

    reader = DatasetReader(dataset)
    first = reader.episodes.iloc[0].to_dict()
    provenance = {k: first[k] for k in ("source", "device", "operator_id", "skill", "seed", "success")}
    recording = save_rrd(out / "demo_vs_bc.rrd", [
        ("script demo", demos[0], provenance),
        ("BC policy", bc.trajectories[0], {"source": "policy", "policy": "BC", "seed": EVAL_SEED}),
    ])
    loss = {k: [row[k] for row in policy.log if k in row] for k in ("train_loss", "val_loss")}
    loss = {k: v for k, v in loss.items() if v}
    summaries = {"oracle rollouts": oracle.summary, "BC policy": bc.summary}
    report = write_report(
        out, f"surrol-data demo: {DEMO_TASK}", demos={"script demos": demos}, evaluations=summaries,
        training_loss=loss or None, rrd_path=recording,
        intro=(f"{episodes} scripted demos of {DEMO_TASK} recorded as a LeRobot v3 dataset, a BC policy "
               f"trained on them, and both policies evaluated on {eval_episodes} unseen seeds "
               f"({EVAL_SEED}…{EVAL_SEED + eval_episodes - 1})."))
    print_summary(console, {"script demos (dataset)": _demo_summary(demos), **summaries})
    console.print(f"\n[bold green]done in {time.perf_counter() - t0:.0f} s[/]")
    for name, path in (("dataset", dataset), ("BC policy", policy_path), ("report", report),
                       ("Rerun recording", recording)):
        console.print(f"  {name:<16} {path}")
    console.print("\n[bold]next[/]")
    for line in next_steps(dataset, recording):
        console.print(f"  {line}", highlight=False, markup=False, soft_wrap=True)  # no line break inside a command
    return DemoOutputs(out, dataset, policy_path, report, recording, summaries)


def default_out() -> Path:
    """A new folder for one demo's outputs: ``outputs/demo-<date>-<time>`` (``-2``, ``-3``, ... within a second)."""
    stem = Path("outputs") / time.strftime("demo-%Y%m%d-%H%M%S")
    out, n = stem, 1
    while out.exists():
        n += 1
        out = stem.with_name(f"{stem.name}-{n}")
    return out


def next_steps(dataset: Path, recording: Path) -> list[str]:
    """What to try after the demo, each with its command as it runs in the user's shell."""
    from surrol_data.viz.open_command import as_run_here, recording_view_command

    cli = as_run_here("surrol-data", "surrol_data.cli")
    return [f"watch a demo beside a BC rollout:  {recording_view_command(recording)}",
            f"look into the dataset:             {cli} info {dataset}",
            f"record 100 demos of your own:      {cli} collect --source script --task {DEMO_TASK} "
            f"--num-episodes 100 --out datasets/{DEMO_TASK}_script",
            f"train the paper's DDPG+BC on them: {cli} train algo=ddpgbc task={DEMO_TASK} demos=script seed=0",
            f"every command:                     {cli} --help"]


def _demo_summary(demos) -> dict:
    from surrol_data.datasets.metrics import summarize, trajectory_proficiency

    return summarize([trajectory_proficiency(t) for t in demos])


def _cell(value: float, fmt: str) -> str:
    """A table cell: ``–`` where a metric has no value (nothing succeeded), never ``nan``."""
    return "–" if value != value else fmt.format(value)


def print_summary(console: Console, summaries: dict) -> None:
    table = Table(title="proficiency (success at any step; steps and path over successful episodes)")
    for col in ("source", "episodes", "success", "final success", "steps to complete", "path length cm"):
        table.add_column(col, justify="right" if col != "source" else "left")
    for name, s in summaries.items():
        table.add_row(name, str(s["episodes"]), _cell(s["success_rate"], "{:.0%}"),
                      _cell(s["final_success_rate"], "{:.0%}"), _cell(s["mean_steps_to_success"], "{:.1f}"),
                      _cell(s["mean_path_length_cm"], "{:.1f}"))
    console.print(table)

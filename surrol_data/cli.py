"""``surrol-data``: the command line of the toolkit (one sub-command per job)."""

from __future__ import annotations

import os
import shlex
import sys
from enum import Enum
from pathlib import Path
from typing import Optional

# Datasets are local: never let lerobot / huggingface_hub reach for the Hub behind the user's back.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("SVT_LOG", "1")

import typer  # noqa: E402
from rich.console import Console  # noqa: E402

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_show_locals=False,
                  help="Surgical-robot learning from demonstrations that know where they came from.")
console = Console()


class Source(str, Enum):
    script = "script"
    haptic = "haptic"


def _fail(message: str) -> None:
    console.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(code=2)


@app.command()
def demo(out: Optional[Path] = typer.Option(None, help="Folder for everything the demo makes (default: a new temp folder)."),
         episodes: int = typer.Option(20, min=1, help="Scripted demos to collect."),
         eval_episodes: int = typer.Option(20, min=1, help="Evaluation episodes per policy."),
         seed: int = typer.Option(0, help="First demo seed.")):
    """Quick end-to-end run: collect NeedlePick script demos, train BC, evaluate, write a report and a Rerun file."""
    from surrol_data.demo import run_demo

    try:
        run_demo(out, episodes=episodes, eval_episodes=eval_episodes, seed=seed, console=console)
    except FileExistsError as e:
        _fail(str(e))


@app.command()
def collect(source: Source = typer.Option(..., help="Where actions come from: the scripted oracle or a teleoperation device."),
            task: str = typer.Option(..., help="Task name, e.g. NeedlePick (see `surrol-data tasks`)."),
            episodes: int = typer.Option(..., min=1, help="Episodes to record (kept ones)."),
            out: Path = typer.Option(..., help="Dataset folder (must not exist unless --append)."),
            seed: int = typer.Option(0, help="Seed of the first attempt; attempt i uses seed + i."),
            max_steps: Optional[int] = typer.Option(None, min=1, help="Episode horizon (default: the task's)."),
            keep_failures: bool = typer.Option(False, help="Also record episodes that never succeeded."),
            append: bool = typer.Option(False, help="Add episodes to an existing dataset.")):
    """Record demonstrations into a LeRobot v3 dataset with per-episode provenance."""
    if source is Source.haptic:
        _fail("--source haptic needs the teleoperation devices, which are not in this version yet; "
              "use --source script")
    from surrol_data.collect.script_source import collect_script

    try:
        result = collect_script(task, episodes, out, seed=seed, max_steps=max_steps, keep_failures=keep_failures,
                                append=append, command=shlex.join(["surrol-data", *sys.argv[1:]]))
    except (ValueError, FileExistsError, RuntimeError) as e:
        _fail(str(e))
    console.print(f"recorded {result.kept} episodes ({result.attempts} attempts, oracle success "
                  f"{result.success_rate:.0%}) into {out}")


@app.command()
def info(dataset: Path = typer.Argument(..., help="Dataset folder.")):
    """Summarise a dataset: counts, features and a provenance breakdown."""
    from surrol_data.datasets.info import render_info
    from surrol_data.datasets.reader import DatasetError

    try:
        console.print(render_info(dataset))
    except DatasetError as e:
        _fail(str(e))


@app.command("eval")
def evaluate_cmd(task: str = typer.Option(..., help="Task name, e.g. NeedlePick."),
                 policy: str = typer.Option("oracle", help="'oracle' or the path of a BC checkpoint (.pt)."),
                 episodes: int = typer.Option(20, min=1),
                 seed: int = typer.Option(0, help="Seed of the first episode; episode i uses seed + i."),
                 max_steps: Optional[int] = typer.Option(None, min=1)):
    """Run a policy for N seeded episodes and print its proficiency metrics."""
    from surrol_data.demo import print_summary
    from surrol_data.envs import env_id
    from surrol_data.evaluation.rollout import evaluate

    try:
        result = evaluate(env_id(task), policy, episodes, seed=seed, max_steps=max_steps)
    except (ValueError, FileNotFoundError) as e:
        _fail(str(e))
    print_summary(console, {f"{policy} on {task}": result.summary})


@app.command("train-bc")
def train_bc_cmd(dataset: Path = typer.Argument(..., help="Dataset folder with demos."),
                 out: Path = typer.Option(..., help="Checkpoint file to write (.pt)."),
                 epochs: int = typer.Option(20, min=1),
                 steps_per_epoch: int = typer.Option(100, min=1),
                 seed: int = typer.Option(0),
                 skill: Optional[str] = typer.Option(None, help="Only episodes of this skill (expert, novice, scripted)."),
                 successful_only: bool = typer.Option(True, help="Only successful episodes.")):
    """Train a behaviour-cloning policy from a dataset's demos (selected by provenance)."""
    from surrol_data.algos.bc import BCConfig, demo_arrays, train_bc
    from surrol_data.datasets.reader import DatasetError, DatasetReader

    try:
        reader = DatasetReader(dataset)
    except DatasetError as e:
        _fail(str(e))
    where = {}
    if skill:
        where["skill"] = skill
    if successful_only:
        where["success"] = True
    episodes = reader.select(where or None)
    if not episodes:
        _fail(f"no episodes of {dataset} match {where}; see `surrol-data info {dataset}`")
    obs, goal, action, episode = demo_arrays(reader.trajectories(episodes))
    policy = train_bc(obs, goal, action, BCConfig(epochs=epochs, steps_per_epoch=steps_per_epoch, seed=seed),
                      episode_index=episode)
    console.print(f"trained on {len(episodes)} episodes ({len(obs)} samples); saved {policy.save(out)}")


@app.command()
def view(dataset: Path = typer.Argument(..., help="Dataset folder."),
         out: Path = typer.Option(..., help="Rerun recording to write (.rrd)."),
         episodes: str = typer.Option("0", help="Comma-separated episode indices to show side by side.")):
    """Write a Rerun recording of dataset episodes (tool paths, goal, actions, jaw, clutch, provenance)."""
    from surrol_data.datasets.reader import DatasetError, DatasetReader
    from surrol_data.viz.rerun_log import save_rrd

    try:
        reader = DatasetReader(dataset)
        wanted = [int(e) for e in episodes.split(",") if e.strip()]
    except (DatasetError, ValueError) as e:
        _fail(str(e))
    table = reader.episodes.set_index("episode_index")
    missing = [e for e in wanted if e not in table.index]
    if missing:
        _fail(f"episodes {missing} are not in {dataset} (it has {len(table)}: {list(table.index)[:10]}...)")
    items = []
    for ep in wanted:
        row = table.loc[ep].to_dict()
        label = f"ep{ep} {row.get('source', '')} {row.get('skill', '')}".strip()
        items.append((label, reader.trajectory(ep), {k: row[k] for k in row if not str(k).startswith("stats")}))
    console.print(f"wrote {save_rrd(out, items)}; open it with: rerun {out}")


@app.command()
def tasks():
    """List the registered tasks with their observation, goal and action sizes and horizons."""
    import gymnasium as gym
    from rich.table import Table

    from surrol_data.envs import TASKS, env_id

    table = Table(title="surrol_data tasks")
    for col in ("task", "env id", "arms", "obs", "goal", "action", "horizon"):
        table.add_column(col)
    for name in TASKS:
        env = gym.make(env_id(name))
        spaces = env.observation_space
        n_arms = env.action_space.shape[0] // 5
        table.add_row(name, env_id(name), "PSM" if n_arms == 1 else "PSM×2", str(spaces["observation"].shape[0]),
                      str(spaces["desired_goal"].shape[0]), str(env.action_space.shape[0]),
                      str(env.spec.max_episode_steps))
        env.close()
    console.print(table)


if __name__ == "__main__":
    app()

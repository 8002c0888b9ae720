"""Simulated expert and novice operators against the script oracle, per task: success, steps, path, clutching.

Usage: ``uv run python benchmarks/operator_tasks.py [--tasks PickAndPlace MatchBoard MatchBoardPanel]
[--operators 2] [--episodes 5]``

Each operator identity (``expert-0``, ``novice-1``, …) does ``episodes`` seeded episodes through the same loop as
``collect --source haptic --device operator`` (operator frames → the device mapping → env actions) with the
haptic session's horizon (3× the task's registered horizon), without recording; the oracle runs the registered
horizon on the same seeds. Proficiency comes from ``surrol_data.evaluation.metrics``, as ``surrol-data info``
computes it for recorded demos. Steps and path are over successful episodes (mean ± sd).
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

import surrol_data.envs
from surrol_data.collect.mapping import ActionMapper, MappingSettings
from surrol_data.collect.operator import SimulatedOperator
from surrol_data.datasets.trajectory import TrajectoryBuilder
from surrol_data.envs import env_id
from surrol_data.evaluation.metrics import Proficiency, trajectory_proficiency

HAPTIC_HORIZON_FACTOR = 3
NEW_TASKS = ["PickAndPlace", "MatchBoard", "MatchBoardPanel"]


def episode(env, seed: int, operator: SimulatedOperator | None, horizon: int) -> Proficiency:
    """One episode driven by ``operator`` (through the mapping) or, None, by the task's oracle."""
    mapper = ActionMapper(operator.mapping) if operator else None
    obs, info = env.reset(seed=seed)
    builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
    for _ in range(horizon):
        if operator is None:
            action, flags = env.unwrapped.oracle_action(obs), {}
        else:
            operator.observe(obs, info)
            step = mapper(operator.read())
            action, flags = step.arm, {"clutch": step.clutch, "jaw_button": step.jaw_button}
        obs, reward, terminated, truncated, info = env.step(action)
        builder.add(action, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    flags=flags)
        if terminated or truncated or (operator is not None and info["is_success"]):
            break
    return trajectory_proficiency(builder.build())


def run(task: str, operators: int, episodes: int, progress: Progress | None = None) -> dict[str, list[Proficiency]]:
    registered = gym.spec(env_id(task)).max_episode_steps
    env = gym.make(env_id(task), max_episode_steps=HAPTIC_HORIZON_FACTOR * registered)
    seeds = [1000 + k for k in range(operators * episodes)]
    bar = progress.add_task(task, total=3 * len(seeds)) if progress else None
    out: dict[str, list[Proficiency]] = {"script oracle": []}
    for seed in seeds:
        out["script oracle"].append(episode(env, seed, None, registered))
        if progress:
            progress.advance(bar)
    for skill in ("expert", "novice"):
        out[skill] = []
        for i in range(operators):
            op = SimulatedOperator(env.unwrapped, skill, f"{skill}-{i}", MappingSettings(), seed=0)
            op.connect()
            for seed in seeds[i * episodes:(i + 1) * episodes]:
                out[skill].append(episode(env, seed, op, HAPTIC_HORIZON_FACTOR * registered))
                if progress:
                    progress.advance(bar)
    env.close()
    return out


def _mean_sd(values) -> str:
    v = np.asarray(values, dtype=np.float64)
    return f"{v.mean():.1f} ± {v.std():.1f}" if len(v) else "—"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=NEW_TASKS, choices=list(surrol_data.envs.TASKS))
    parser.add_argument("--operators", type=int, default=2, help="identities per skill")
    parser.add_argument("--episodes", type=int, default=5, help="episodes per identity")
    args = parser.parse_args()
    table = Table(title=f"simulated operators vs the script oracle ({args.operators} identities × {args.episodes} "
                        "episodes per skill; operators get 3× the registered horizon)")
    for col in ("task", "source", "success", "steps to success", "path (cm)", "clutch uses / ep"):
        table.add_column(col, justify="left" if col in ("task", "source") else "right")
    with Progress(transient=True) as progress:
        results = {task: run(task, args.operators, args.episodes, progress) for task in args.tasks}
    for task, by_source in results.items():
        for source, scores in by_source.items():
            ok = [s for s in scores if s.success]
            table.add_row(task, source, f"{len(ok)}/{len(scores)}", _mean_sd([s.steps_to_success for s in ok]),
                          _mean_sd([s.path_length_cm for s in ok]), f"{np.mean([s.clutch_uses for s in scores]):.1f}")
    Console(width=140).print(table)


if __name__ == "__main__":
    main()

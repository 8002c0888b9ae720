"""Simulated operators against the script oracle on NeedlePick: success, time, path, smoothness, clutching.

Usage: ``uv run python benchmarks/operator_profiles.py [--identities 3] [--episodes 10] [--horizon 150]``

Each profile (expert, novice) runs ``identities`` operators × ``episodes`` seeded 150-step attempts (the
paper's human recording length) through the real device mapping into the env; the oracle runs the same seeds.
Means ± standard deviations are over the successful attempts.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.mapping import ActionMapper, MappingSettings
from surrol_data.collect.operator import SimulatedOperator
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.trajectory import TrajectoryBuilder
from surrol_data.evaluation.rollout import ORACLE, rollout

FIRST_SEED = 1000


def operator_episode(env, operator: SimulatedOperator, seed: int, horizon: int):
    mapper = ActionMapper(operator.mapping)
    obs, info = env.reset(seed=seed)
    builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
    for _ in range(horizon):
        operator.observe(obs, info)
        step = mapper(operator.read())
        obs, reward, terminated, truncated, info = env.step(step.arm)
        builder.add(step.arm, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    flags={"clutch": step.clutch, "jaw_button": step.jaw_button})
        if terminated or truncated:
            break
    return trajectory_proficiency(builder.build())


def summarise(name: str, scores: list) -> list[str]:
    ok = [s for s in scores if s.success]

    def stat(field, fmt="{:.1f}"):
        v = np.array([getattr(s, field) for s in ok], np.float64)
        return "—" if not len(v) else f"{fmt.format(v.mean())} ± {fmt.format(v.std())}"

    ldlj = np.mean([s.log_dimensionless_jerk for s in ok]) if ok else float("nan")
    return [name, f"{len(ok)}/{len(scores)}", stat("steps_to_success"), stat("path_length_cm"), f"{ldlj:.1f}",
            f"{np.mean([s.clutch_uses for s in scores]):.1f}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--identities", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--horizon", type=int, default=150)
    args = parser.parse_args()
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=args.horizon)
    n = args.identities * args.episodes
    seeds = range(FIRST_SEED, FIRST_SEED + n)
    with Progress(transient=True) as progress:
        bar = progress.add_task("episodes", total=3 * n)
        oracle = []
        for s in seeds:
            oracle.append(trajectory_proficiency(rollout(env, ORACLE, s)))
            progress.advance(bar)
        rows = [summarise("script oracle", oracle)]
        for skill in ("expert", "novice"):
            scores = []
            for i in range(args.identities):
                op = SimulatedOperator(env.unwrapped, skill, f"{skill}-{i}", MappingSettings(), 0)
                op.connect()
                for k in range(args.episodes):
                    scores.append(operator_episode(env, op, FIRST_SEED + i * args.episodes + k, args.horizon))
                    progress.advance(bar)
            rows.append(summarise(skill, scores))
    env.close()
    table = Table(title=f"simulated operators on NeedlePick ({args.horizon}-step attempts, {args.identities} "
                        f"identities × {args.episodes} episodes per profile)")
    for col in ("source", "success", "steps to success", "path (cm)", "smoothness (LDLJ)", "clutch uses / ep"):
        table.add_column(col, justify="left" if col == "source" else "right")
    for row in rows:
        table.add_row(*row)
    Console(width=140).print(table)


if __name__ == "__main__":
    main()

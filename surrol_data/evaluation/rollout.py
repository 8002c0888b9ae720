"""Roll a policy out in an env and score it with the same metrics that score human demos.

A policy is any callable ``obs_dict -> action`` (one with a ``reset()`` method, e.g. a chunking LeRobot
policy, is reset at every episode start), or the string ``"oracle"`` for the env's scripted oracle
(``env.unwrapped.oracle_action``); it may name ``torch_threads`` (BC and DDPG actors: 1), which
:func:`evaluate` runs it with, restoring the count afterwards, and ``env_kwargs`` the env needs (a camera).
One episode is :func:`surrol_data.collect.rollout.rollout`. Turning a spec from the command line (``"oracle"``,
``"lerobot:DIR"`` or a checkpoint path) into a policy is :func:`surrol_data.algos.policies.load_policy`:
evaluation never imports the learners.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm.auto import tqdm

from surrol_data.collect.rollout import ORACLE, Policy, rollout
from surrol_data.datasets.metrics import Proficiency, summarize, trajectory_proficiency
from surrol_data.datasets.trajectory import Trajectory

# Evaluation seeds start here: collectors number demo episodes from 0 (and --append continues the sequence), so a
# policy is never scored on an episode it may have seen as a demonstration. Training evaluation uses the same base.
EVAL_SEED_BASE = 1_000_000_000


@dataclass
class EvalResult:
    env_id: str
    seeds: list[int]
    proficiency: list[Proficiency]
    summary: dict
    trajectories: list[Trajectory] = field(default_factory=list)  # empty unless asked for

    def as_record(self, policy: str) -> dict:
        """What an evaluation file records: task, policy, seeds, the summary and every episode's metrics."""
        task = self.env_id.split("/")[-1].rsplit("-v", 1)[0]
        return {"task": task, "env_id": self.env_id, "policy": policy, "seeds": list(self.seeds),
                "summary": self.summary, "episodes": [p.as_dict() for p in self.proficiency]}


def evaluate(env_id: str, policy: Policy | str, episodes: int, seed: int = EVAL_SEED_BASE, max_steps: int | None = None,
             progress: bool = True, keep_trajectories: bool = False, env_kwargs: dict | None = None) -> EvalResult:
    """Roll ``policy`` out for ``episodes`` episodes with seeds ``seed, seed+1, …`` and score each one.

    ``max_steps`` overrides the registered horizon (the env is made with that time limit). ``policy`` is a
    callable or ``"oracle"``; load a checkpoint or ``lerobot:DIR`` with
    :func:`surrol_data.algos.policies.load_policy` first.
    """
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    if isinstance(policy, (str, Path)):
        if str(policy) != ORACLE:
            raise ValueError(f"policy {str(policy)!r} is a spec, not a policy: evaluate takes a callable obs -> "
                             f"action or {ORACLE!r}; load a checkpoint or lerobot:DIR with "
                             "surrol_data.algos.policies.load_policy first")
        policy = ORACLE
    import surrol_data.envs  # noqa: F401  (registers the SurRoL/* ids)

    kwargs = {**getattr(policy, "env_kwargs", {}), **(env_kwargs or {})}  # e.g. a camera the policy looks through
    if max_steps is not None:
        kwargs["max_episode_steps"] = max_steps
    env = gym.make(env_id, **kwargs)
    seeds = [seed + i for i in range(episodes)]
    scores: list[Proficiency] = []
    kept: list[Trajectory] = []
    bar = tqdm(total=episodes, desc=f"eval {env_id}", disable=not progress, leave=False)
    try:
        with policy_threads(policy):
            for s in seeds:
                traj = rollout(env, policy, s, max_steps)
                scores.append(trajectory_proficiency(traj))
                if keep_trajectories:
                    kept.append(traj)
                bar.set_postfix(success=f"{np.mean([p.success for p in scores]):.2f}", refresh=False)
                bar.update(1)
    finally:
        bar.close()
        env.close()
    return EvalResult(env_id=env_id, seeds=seeds, proficiency=scores, summary=summarize(scores), trajectories=kept)


@contextmanager
def policy_threads(policy: Policy | str):
    """Run the block with torch set to the policy's ``torch_threads`` (a BC/DDPG actor: 1), then restore the
    caller's count; a policy without that attribute (the oracle, a LeRobot policy) runs as it is."""
    wanted = getattr(policy, "torch_threads", None)
    torch = sys.modules.get("torch")  # a policy that names threads has imported torch already
    if wanted is None or torch is None or torch.get_num_threads() == wanted:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(int(wanted))
    try:
        yield
    finally:
        torch.set_num_threads(previous)

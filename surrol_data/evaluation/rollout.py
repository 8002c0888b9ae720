"""Roll a policy out in an env and score it with the same metrics that score human demos.

A policy is any callable ``obs_dict -> action`` (one with a ``reset()`` method, e.g. a chunking LeRobot
policy, is reset at every episode start), or the string ``"oracle"`` for the env's scripted oracle
(``env.unwrapped.oracle_action``). :func:`load_policy` turns a spec from the command line (``"oracle"``,
``"lerobot:DIR"`` or a checkpoint path) into one of those. :func:`evaluate` runs a policy that names its
``torch_threads`` (BC and DDPG actors: 1) with that many torch threads, and restores the count afterwards.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm.auto import tqdm

from surrol_data.datasets.trajectory import Trajectory, TrajectoryBuilder
from surrol_data.evaluation.metrics import Proficiency, summarize, trajectory_proficiency

ORACLE = "oracle"
Policy = Callable[[dict], np.ndarray]


def load_policy(spec: str | Path) -> Policy | str:
    """``"oracle"`` stays the string (it is bound to an env at rollout time); ``"lerobot:DIR"`` is a policy trained
    by ``lerobot-train`` (:mod:`surrol_data.evaluation.lerobot_policy`); anything else is a BC checkpoint path."""
    if str(spec) == ORACLE:
        return ORACLE
    if str(spec).startswith("lerobot:"):
        from surrol_data.evaluation.lerobot_policy import load_lerobot_policy

        return load_lerobot_policy(str(spec))
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"policy spec {str(spec)!r} is neither {ORACLE!r}, lerobot:DIR nor an existing "
                                "checkpoint file")
    from surrol_data.algos.bc import BCPolicy  # only checkpoint users pay for importing torch

    return BCPolicy.load(path)


def rollout(env: gym.Env, policy: Policy | str, seed: int, max_steps: int | None = None) -> Trajectory:
    """One episode from ``env.reset(seed=seed)`` until terminated or truncated, or ``max_steps`` actions.

    The whole horizon is run even after success (as SurRoL's demo generator does), so both the any-time
    and the final-step success conventions can be read from the trajectory.
    """
    act = _bind(env, policy)
    if max_steps is None and (env.spec is None or env.spec.max_episode_steps is None):
        raise ValueError("the env has no time limit; pass max_steps or make it with gymnasium.make(..., max_episode_steps=T)")
    space = env.action_space

    obs, info = env.reset(seed=seed)
    reset = getattr(act, "reset", None)
    if callable(reset):
        reset()  # stateful policies (action chunks, history) start each episode afresh
    builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
    while max_steps is None or len(builder) < max_steps:
        action = np.asarray(act(obs), np.float32)
        if action.shape != space.shape:
            raise ValueError(f"policy returned an action of shape {action.shape}, the env expects {space.shape}")
        # Record exactly what the env executes: the env clips too, but the trajectory must hold the clipped value.
        action = np.clip(action, space.low, space.high)
        obs, reward, terminated, truncated, info = env.step(action)
        builder.add(action, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    info=info)
        if terminated or truncated:
            break
    return builder.build()


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

    ``max_steps`` overrides the registered horizon (the env is made with that time limit).
    ``policy`` may also be a spec string for :func:`load_policy`.
    """
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    if isinstance(policy, (str, Path)):
        policy = load_policy(policy)
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


def _bind(env: gym.Env, policy: Policy | str) -> Policy:
    if isinstance(policy, str):
        if policy != ORACLE:
            raise ValueError(f"unknown policy string {policy!r}; use {ORACLE!r} or load a checkpoint with load_policy")
        oracle = getattr(env.unwrapped, "oracle_action", None)
        if oracle is None:
            raise ValueError(f"{type(env.unwrapped).__name__} has no oracle_action; only SurRoL tasks have an oracle")
        return oracle
    if not callable(policy):
        raise TypeError(f"policy must be a callable obs_dict -> action or {ORACLE!r}, got {type(policy).__name__}")
    return policy

"""Roll a policy out in an env into a :class:`~surrol_data.datasets.trajectory.Trajectory`.

A policy is any callable ``obs_dict -> action`` (one with a ``reset()`` method, e.g. a chunking LeRobot
policy, is reset at every episode start), or the string ``"oracle"`` for the env's scripted oracle
(``env.unwrapped.oracle_action``). The scripted collector records these episodes as demos;
:mod:`surrol_data.evaluation.rollout` scores them.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from surrol_data.datasets.trajectory import Trajectory, TrajectoryBuilder

ORACLE = "oracle"
Policy = Callable[[dict], np.ndarray]


def rollout(env: gym.Env, policy: Policy | str, seed: int, max_steps: int | None = None) -> Trajectory:
    """One episode from ``env.reset(seed=seed)`` until terminated or truncated, or ``max_steps`` actions.

    The whole horizon is run even after success (as SurRoL's demo generator does), so both the any-time
    and the final-step success conventions can be read from the trajectory.
    """
    act = bind_policy(env, policy)
    if max_steps is None and (env.spec is None or env.spec.max_episode_steps is None):
        raise ValueError("the env has no time limit; pass max_steps or make it with gymnasium.make(..., max_episode_steps=T)")

    space = env.action_space

    obs, info = env.reset(seed=seed)
    start_episode(act)
    builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
    while max_steps is None or len(builder) < max_steps:
        action = policy_action(act, obs, space)
        obs, reward, terminated, truncated, info = env.step(action)
        builder.add(action, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    info=info)
        if terminated or truncated:
            break
    return builder.build()


def start_episode(act: Policy) -> None:
    """Call after every ``env.reset``: stateful policies (action chunks, history) start each episode afresh."""
    reset = getattr(act, "reset", None)
    if callable(reset):
        reset()


def policy_action(act: Policy, obs: dict, space: gym.spaces.Box) -> np.ndarray:
    """The policy's action for ``obs``, checked against the action space and clipped to it."""
    action = np.asarray(act(obs), np.float32)
    if action.shape != space.shape:
        raise ValueError(f"policy returned an action of shape {action.shape}, the env expects {space.shape}")
    # Record exactly what the env executes: the env clips too, but the trajectory must hold the clipped value.
    return np.clip(action, space.low, space.high)


def bind_policy(env: gym.Env, policy: Policy | str) -> Policy:
    """The callable of ``policy`` (the env's oracle for :data:`ORACLE`), or a clear error."""
    if isinstance(policy, str):
        if policy != ORACLE:
            raise ValueError(f"unknown policy string {policy!r}; use {ORACLE!r} or load a checkpoint with "
                             "surrol_data.algos.policies.load_policy")
        oracle = getattr(env.unwrapped, "oracle_action", None)
        if oracle is None:
            raise ValueError(f"{type(env.unwrapped).__name__} has no oracle_action; only SurRoL tasks have an oracle")
        return oracle
    if not callable(policy):
        raise TypeError(f"policy must be a callable obs_dict -> action or {ORACLE!r}, got {type(policy).__name__}")
    return policy

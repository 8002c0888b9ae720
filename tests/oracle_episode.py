"""Shared by the task tests: make each task's env once per module, and roll its oracle for one seeded episode."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)


def task_env_fixture(tasks: list[str]):
    """A module-scoped fixture that yields ``gymnasium.make("SurRoL/<task>-v0")`` for each task."""

    @pytest.fixture(scope="module", params=tasks)
    def env(request):
        e = gym.make(f"SurRoL/{request.param}-v0")
        yield e
        e.close()

    return env


@dataclass
class OracleEpisode:
    observations: np.ndarray   # (T+1, obs_dim), the reset observation first
    rewards: np.ndarray        # (T,)
    successes: np.ndarray      # (T,) info["is_success"]
    grasped: np.ndarray        # (T, ...) info["grasped"] (False where a task has no grasp)


def oracle_until(task: str, seed: int, reached, steps: int = 50):
    """A fresh ``SurRoL/<task>-v0`` under its oracle until ``reached(unwrapped_env)`` holds (at most ``steps``
    steps): (env, its unwrapped env, the last observation, the last info)."""
    env = gym.make(f"SurRoL/{task}-v0")
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    for _ in range(steps):
        obs, _, _, _, info = env.step(u.oracle_action(obs))
        if reached(u):
            return env, u, obs, info
    pytest.fail(f"{task} seed {seed}: the oracle never reached the state the test needs in {steps} steps")


def run_oracle(env, seed: int, steps: int | None = None) -> OracleEpisode:
    """The oracle for ``steps`` steps (default: the horizon), stopping early if the episode ends."""
    obs, info = env.reset(seed=seed)
    observations, rewards, successes, grasped = [obs["observation"]], [], [], []
    for _ in range(steps or env.spec.max_episode_steps):
        obs, reward, terminated, truncated, info = env.step(env.unwrapped.oracle_action(obs))
        observations.append(obs["observation"])
        rewards.append(reward)
        successes.append(info["is_success"])
        grasped.append(info.get("grasped", False))
        if terminated or truncated:
            break
    return OracleEpisode(np.array(observations), np.array(rewards), np.array(successes), np.array(grasped))


def assert_same_episode(a: OracleEpisode, b: OracleEpisode) -> None:
    """Bit-identical: equal seeds must give equal episodes whatever ran in between."""
    for name in ("observations", "rewards", "successes", "grasped"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)

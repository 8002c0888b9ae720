"""The induced-failure probe on the real NeedlePick scene: it disables exactly one attempt, the first near the needle."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.rollout import rollout
from surrol_data.datasets.attempts import Outcome, trajectory_attempts
from surrol_data.evaluation.grip_probe import InducedFailure

HORIZON = 70


class RetryingOracle:
    """The oracle, made to reopen and grasp again (from above the needle, re-planned where it now lies) whenever it
    is past its closing waypoint without holding the needle: a policy that retries, as people do."""

    def __init__(self, env):
        self.base = env.unwrapped

    def __call__(self, obs):
        base = self.base
        if base._wp_index >= 3 and not base.grasp.attached:
            base._waypoints, base._wp_index, base._hold = base.plan_oracle(), 0, 0
        return base.oracle_action(obs)


class GripLog(gym.Wrapper):
    """Keeps each step's ``grip_disabled`` from the probe's info."""

    def reset(self, **kwargs):
        self.disabled = []
        return self.env.reset(**kwargs)

    def step(self, action):
        out = self.env.step(action)
        self.disabled.append(out[4]["grip_disabled"])
        return out


@pytest.fixture(scope="module")
def env():
    e = GripLog(InducedFailure(gym.make("SurRoL/NeedlePick-v0", max_episode_steps=HORIZON)))
    yield e
    e.close()


@pytest.mark.parametrize("seed", [0, 1])
def test_the_probe_disables_exactly_the_first_attempt(env, seed):
    traj = rollout(env, RetryingOracle(env), seed)
    record, probe = trajectory_attempts(traj), env.env.record
    first, *later = record.attempts
    assert probe.spent and probe.prevented_grip and probe.disabled_from == first.start
    assert first.failed and not first.held           # the disabled attempt: the blades closed on nothing
    assert later and later[0].retry and later[0].held and later[0].lifted   # the next one grips as usual
    disabled = np.flatnonzero(env.disabled)
    assert disabled.tolist() == list(range(first.start, first.end))   # the grip was off during that attempt only
    assert record.outcome is Outcome.RECOVERED and traj.final_success


def test_the_oracle_never_retries_so_the_probe_makes_it_stall(env):
    traj = rollout(env, "oracle", 0)
    assert trajectory_attempts(traj).outcome is Outcome.STALL and not traj.final_success
    plain = rollout(env.env.env, "oracle", 0)   # without the probe the same episode's first attempt holds
    assert trajectory_attempts(plain).outcome is Outcome.FIRST_HELD and plain.final_success


def test_a_flicker_near_the_needle_does_not_spend_the_probe(env):
    base = env.unwrapped
    oracle = RetryingOracle(env)
    flickered = []

    def flicker_first(obs):   # the oracle, with one one-step close at the grasp point before its real one
        action = oracle(obs)
        if action[4] < 0 and not flickered:
            flickered.append(True)
            return action
        if flickered and len(flickered) == 1:
            flickered.append(True)
            return np.concatenate([action[:4], [1.0]]).astype(np.float32)
        return action

    traj = rollout(env, flicker_first, 0)
    assert base.grasp is env.env._grasp
    probe, record = env.env.record, trajectory_attempts(traj)
    assert probe.spent and probe.disabled_from == record.attempts[0].start > 0
    assert record.attempts[0].failed and record.outcome is Outcome.RECOVERED


def test_tasks_without_one_grasp_are_refused():
    with pytest.raises(ValueError, match="one-arm tasks that grasp"):
        InducedFailure(gym.make("SurRoL/NeedleReach-v0"))

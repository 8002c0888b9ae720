"""PegBoard: Gymnasium API, the ring's start and goal, the success test, determinism, the need to turn the ring,
and oracle success."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import physics, ring_board

from oracle_episode import assert_same_episode, run_oracle


@pytest.fixture(scope="module")
def env():
    e = gym.make("SurRoL/PegBoard-v0")
    yield e
    e.close()


def test_check_env_passes(env):
    check_env(env.unwrapped, skip_render_check=True)


def test_ring_hangs_upright_on_a_panel_peg_and_the_goal_is_a_floor_peg(env):
    goals = set()
    for seed in range(12):
        obs, info = env.reset(seed=seed)
        centre, rot = ring_board.ring_pose(env.unwrapped.client, env.unwrapped.object_id)
        np.testing.assert_allclose(obs["achieved_goal"], centre, atol=1e-6)
        assert ring_board.ring_tilt(rot) > np.deg2rad(85)          # upright, axis along y
        peg = env.unwrapped.board.hanging_centre(env.unwrapped.start_peg)
        assert abs(centre[0] - peg[0]) < 5e-4 and abs(centre[2] - peg[2]) < 5e-4   # resting on its peg
        assert info["is_success"] == 0.0
        goal = obs["desired_goal"]
        assert any(np.allclose(goal[:2], xy) for xy in ring_board.FLOOR_PEG_XY)
        assert goal[2] == pytest.approx(ring_board.resting_centre_z())
        goals.add(tuple(np.round(goal, 4)))
    assert len(goals) > 1


def test_compute_reward_is_batched(env):
    u = env.unwrapped
    goal = np.array([0.55, 0.015, ring_board.resting_centre_z()])
    achieved = goal + np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.003], [0.006, 0.0, 0.0], [0.0, 0.0, 0.005]])
    np.testing.assert_array_equal(u.compute_reward(achieved, np.tile(goal, (4, 1)), None), [0, 0, -1, -1])


def test_an_upright_ring_does_not_thread_a_floor_peg():
    """Lowered upright over a floor peg, the ring lands on the peg; turned flat it threads: the wrist matters."""
    e = gym.make("SurRoL/PegBoard-v0")
    u = e.unwrapped
    threaded = {}
    try:
        for name, rotation in (("upright", ring_board.HANGING), ("flat", np.eye(3))):
            e.reset(seed=0)
            x, y = ring_board.FLOOR_PEG_XY[1]
            start = np.array([x, y, u.board.floor_peg_top_z + ring_board.RING_OUTER_RADIUS + 0.002])
            ring_board.set_ring_pose(u.client, u.object_id, start, rotation)
            u.client.changeDynamics(u.object_id, -1, activationState=physics.pb.ACTIVATION_STATE_WAKE_UP)
            u.simulate(120)
            threaded[name] = bool(u.is_success(u.achieved_goal(), np.array([x, y, ring_board.resting_centre_z()])))
    finally:
        e.close()
    assert threaded == {"upright": False, "flat": True}


def test_equal_seeds_give_equal_episodes(env):
    first = run_oracle(env, seed=11)
    assert run_oracle(env, seed=12, steps=25).grasped[-1]   # interrupted with the ring in hand
    assert_same_episode(first, run_oracle(env, seed=11))


@pytest.mark.parametrize("episodes", [5, pytest.param(100, marks=pytest.mark.slow)])
def test_oracle_success_rate(env, episodes):
    results = [run_oracle(env, seed).successes[-1] for seed in range(episodes)]   # success at the last step
    assert np.mean(results) >= 0.95

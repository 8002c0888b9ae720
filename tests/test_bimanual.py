"""The bimanual PSM pair: NeedleRegrasp and BiPegTransfer — API, determinism, hand-over and oracle success."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs.bimanual_env import approach_direction

from oracle_episode import assert_same_episode, run_oracle, task_env_fixture

TASKS = ["NeedleRegrasp", "BiPegTransfer"]
# Oracle success at the final step: ≥ 99 % (issue 11), above the reference SurRoL's 0.98 and 0.94.
env = task_env_fixture(TASKS)



def test_check_env_passes(env):
    check_env(env.unwrapped, skip_render_check=True)


def test_spaces_and_info(env):
    assert env.spec.max_episode_steps == 50
    assert env.action_space.shape == (10,)
    obs, info = env.reset(seed=0)
    assert obs["observation"].shape == (35,) and obs["achieved_goal"].shape == (3,)
    assert all(v.dtype == np.float32 for v in obs.values())
    assert info["tip_position"].shape == (2, 3) and info["tip_position"].dtype == np.float32
    assert info["jaw_angle"].shape == (2,) and info["jaw_angle"].dtype == np.float32
    np.testing.assert_array_equal(info["tip_position"][1], obs["observation"][7:10])
    # Tips in real metres over the table; PSM1 on the +y side, PSM2 on the −y side.
    assert np.all(np.abs(info["tip_position"][:, 2] - 0.72) < 0.05)
    assert info["tip_position"][0, 1] > info["tip_position"][1, 1]


def test_wrong_action_shape_is_refused(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="10-D action"):
        env.unwrapped.step(np.zeros(5, np.float32))


def test_equal_seeds_give_equal_episodes(env):
    first = run_oracle(env, seed=11, steps=40)
    run_oracle(env, seed=12, steps=10)
    assert_same_episode(first, run_oracle(env, seed=11, steps=40))
    assert not np.allclose(env.reset(seed=11)[0]["desired_goal"], env.reset(seed=13)[0]["desired_goal"])


def test_compute_reward_is_batched_and_matches_info(env):
    obs, _ = env.reset(seed=3)
    u = env.unwrapped
    dg = np.repeat(obs["desired_goal"][None], 3, axis=0)
    ag = dg + np.array([[0.0, 0.0, 0.0], [0.003, 0.0, 0.002], [0.0, 0.006, 0.0]])
    np.testing.assert_array_equal(u.compute_reward(ag, dg, None), [0.0, 0.0, -1.0])
    obs, reward, *_, info = env.step(np.zeros(10, np.float32))
    assert reward == info["is_success"] - 1.0


def test_rotation_modes_turn_each_tool_by_its_unit():
    # NeedleRegrasp's arms tilt (pitch mode, 15° per unit, the "roll" term); BiPegTransfer's turn (yaw, 30°).
    for task, term, unit in (("NeedleRegrasp", 3, 15.0), ("BiPegTransfer", 5, 30.0)):
        e = gym.make(f"SurRoL/{task}-v0")
        obs, _ = e.reset(seed=0)
        before = obs["observation"][7 + term]
        action = np.zeros(10, np.float32)
        action[9] = 1.0             # PSM2 open: nothing held, the tool turns freely
        action[8] = 0.5             # half a unit
        for _ in range(3):
            obs, *_ = e.step(action)
            action[8] = 0.0
        assert np.rad2deg(obs["observation"][7 + term] - before) == pytest.approx(unit / 2, abs=1.0)
        e.close()


def test_needle_regrasp_starts_in_psm1s_hand():
    e = gym.make("SurRoL/NeedleRegrasp-v0")
    for seed in range(3):
        obs, info = e.reset(seed=seed)
        assert info["grasped"].tolist() == [True, False]
        start = obs["achieved_goal"].copy()
        # Held still with the jaw closed, the needle stays where it was put (no drop, no slip).
        hold = np.array([0, 0, 0, 0, -1, 0, 0, 0, 0, 1], np.float32)
        for _ in range(5):
            obs, *_, info = e.step(hold)
        assert info["grasped"].tolist() == [True, False]
        assert np.linalg.norm(obs["achieved_goal"] - start) < 1e-3
        # Key point 5 sits between PSM1's blades, just inside their ends along the tool axis.
        tip = obs["observation"][0:3]
        key_point_5 = obs["observation"][29:32]
        along = np.dot(tip - key_point_5, approach_direction(float(obs["observation"][3])))
        assert np.linalg.norm(tip - key_point_5) < 3e-3 and 0.0 < along < 3e-3
    # Opening PSM1's jaw drops the needle.
    z0 = obs["achieved_goal"][2]
    for _ in range(3):
        obs, *_, info = e.step(np.array([0, 0, 0, 0, 1, 0, 0, 0, 0, 1], np.float32))
    assert not info["grasped"].any() and obs["achieved_goal"][2] < z0 - 0.005
    e.close()


def test_hand_over_leaves_the_needle_with_psm2_only():
    e = gym.make("SurRoL/NeedleRegrasp-v0")
    u = e.unwrapped
    obs, info = e.reset(seed=4)
    history = []
    for _ in range(40):
        obs, *_, info = e.step(u.oracle_action(obs))
        history.append(tuple(info["grasped"]))
        if history[-1] == (False, True):
            break
    # The oracle's hand-over: PSM1 alone, then both for a moment, then PSM2 alone.
    assert history[0] == (True, False) and (True, True) in history and history[-1] == (False, True)
    # Carried by PSM2 alone: the needle follows PSM2's tip; PSM1 (open) is not involved.
    tip1, tip2, needle = obs["observation"][0:3].copy(), obs["observation"][7:10].copy(), obs["achieved_goal"].copy()
    move = np.array([0, 0, 0, 0, 1, 0.4, -0.6, 0.3, 0, -1], np.float32)
    for _ in range(4):
        obs, *_, info = e.step(move)
    assert tuple(info["grasped"]) == (False, True)
    tip2_moved = obs["observation"][7:10] - tip2
    assert np.linalg.norm(tip2_moved) > 0.02
    np.testing.assert_allclose(obs["achieved_goal"] - needle, tip2_moved, atol=1e-3)
    assert np.linalg.norm(obs["observation"][0:3] - tip1) < 1e-3
    e.close()


def test_bi_peg_transfer_hands_the_block_from_psm2_to_psm1():
    e = gym.make("SurRoL/BiPegTransfer-v0")
    episode = run_oracle(e, seed=5)
    successes, grasped = episode.successes, episode.grasped
    states = [tuple(g) for g in grasped]
    first = {s: states.index(s) for s in set(states)}
    # PSM2 picks it up, both hold it, then PSM1 alone carries it; it ends released on the goal peg.
    assert first[(False, True)] < first[(True, True)] < first[(True, False)]
    assert states[-1] == (False, False) and successes[-1] == 1.0
    e.close()


@pytest.mark.parametrize("episodes", [20, pytest.param(100, marks=pytest.mark.slow)])
@pytest.mark.parametrize("task", TASKS)
def test_oracle_success_rate(task, episodes):
    e = gym.make(f"SurRoL/{task}-v0")
    results = [run_oracle(e, seed).successes[-1] for seed in range(episodes)]
    e.close()
    assert np.mean(results) >= 0.99   # issue 11: every oracle ≥ 99 % (the reference's own may be lower)


def test_camera_option_survives_the_per_episode_rebuild():
    # Each reset rebuilds the world, the camera's still ECM included: the image must keep showing the scene.
    e = gym.make("SurRoL/NeedleRegrasp-v0", camera=True, camera_size=(64, 48))
    first, _ = e.reset(seed=0)
    obs, *_ = e.step(np.zeros(10, np.float32))
    again, _ = e.reset(seed=0)
    assert e.observation_space.contains(again) and again["image"].shape == (48, 64, 3)
    np.testing.assert_array_equal(again["image"], first["image"])
    assert again["image"].std() > 5.0          # a scene, not a blank frame
    other, _ = e.reset(seed=1)                 # another needle pose, another picture
    assert not np.array_equal(other["image"], first["image"])
    e.close()


@pytest.mark.parametrize("task, seed", [("BiPegTransfer", 0), ("NeedleRegrasp", 1), ("NeedleRings", 2)])
def test_hand_over_drives_the_object_by_one_constraint_and_no_blade_sinks_into_it(task, seed):
    """While both hands hold the object, only the giving hand's constraint drives it; the receiving hand squeezes
    it with blades that still collide with it, and takes it when the giver opens. Two welds at once made a rigid
    loop through both force-limited arms (BiPegTransfer's oracle: a blade 1.4 mm inside the block)."""
    from surrol_data.envs.units import SCALING

    e = gym.make(f"SurRoL/{task}-v0")
    u = e.unwrapped
    obs, info = e.reset(seed=seed)
    deepest = [0.0]

    def overlap(env):
        for g in env.grasps:
            for p in env.client.getClosestPoints(g.psm.body, env.object_id, 0.0):
                deepest[0] = max(deepest[0], -p[8] / SCALING)

    u.substep_hook = overlap
    both, owners = 0, []   # owners: per step, the arm whose constraint drives the object (None: none)
    for _ in range(e.spec.max_episode_steps):
        obs, _, _, _, info = e.step(u.oracle_action(obs))
        owners.append(next((k for k, g in enumerate(u.grasps) if g.constraint is not None), None))
        if all(info["grasped"]):
            both += 1
            assert sum(g.constraint is not None for g in u.grasps) == 1
            passive = next(g for g in u.grasps if g.passive)
            for j in (6, 7):   # the squeezing hand's blades collide with the object (no pair filter)
                assert u.client.getContactPoints(passive.psm.body, u.object_id, j) or \
                    u.client.getClosestPoints(passive.psm.body, u.object_id, 0.0005 * SCALING, j)
    u.substep_hook = None
    e.close()
    # The giver's constraint passed straight to the receiver (no step in between with nothing holding it).
    assert both >= 2 and any(a is not None and b is not None and a != b for a, b in zip(owners, owners[1:]))
    assert info["is_success"] == 1.0
    assert deepest[0] <= 1e-3

"""The paper's single-arm training tasks (PickAndPlace, MatchBoard, MatchBoardPanel): Gymnasium API, goals and
success as the paper words them, the physics their success rests on, determinism and oracle success."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import jacks, physics
from surrol_data.envs import match_board as mb

from oracle_episode import assert_same_episode, run_oracle, task_env_fixture

TASKS = ["PickAndPlace", "MatchBoard"]
env = task_env_fixture(TASKS)


def test_check_env_passes(env):
    check_env(env.unwrapped, skip_render_check=True)


def test_equal_seeds_give_equal_episodes(env):
    first = run_oracle(env, seed=5, steps=40)
    # An interrupting episode that ends with the object in hand: nothing of it may leak into the next one.
    assert run_oracle(env, seed=6, steps=20).grasped[-1]
    assert_same_episode(first, run_oracle(env, seed=5, steps=40))
    assert not np.allclose(env.reset(seed=5)[0]["desired_goal"], env.reset(seed=7)[0]["desired_goal"])


def test_compute_reward_is_batched_and_matches_info(env):
    u = env.unwrapped
    obs, info = env.reset(seed=2)
    for _ in range(env.spec.max_episode_steps):
        obs, reward, *_, info = env.step(u.oracle_action(obs))
    assert info["is_success"] == 1.0 and reward == 0.0
    ag = np.stack([obs["achieved_goal"], obs["achieved_goal"] + 0.02, obs["achieved_goal"]])
    dg = np.stack([obs["desired_goal"]] * 3)
    dg[2, -1] += 0.01
    np.testing.assert_array_equal(u.compute_reward(ag, dg, None), [0.0, -1.0, -1.0])


# ---------------------------------------------------------------------------------------------- PickAndPlace
def test_pick_and_place_goals_report_every_jack_and_their_trays():
    e = gym.make("SurRoL/PickAndPlace-v0")
    u = e.unwrapped
    n = len(u.COLOURS)
    assert e.spec.max_episode_steps == 100
    slots = set()
    for seed in range(12):
        obs, _ = e.reset(seed=seed)
        assert obs["achieved_goal"].shape == obs["desired_goal"].shape == (3 * n,)
        assert obs["observation"].shape == (19 + 3 * n,)
        np.testing.assert_allclose(obs["observation"][19:], obs["achieved_goal"])        # every jack observed
        centres = obs["achieved_goal"].reshape(n, 3)
        # Jacks stand on three arm ends on the table, apart; goals are their trays' centres at resting height.
        np.testing.assert_allclose(centres[:, 2], jacks.objects.TABLE_TOP_Z + jacks.JACK_REST_HEIGHT, atol=3e-4)
        assert np.linalg.norm(centres[0, :2] - centres[1, :2]) >= u.JACK_SPACING_M - 1e-6
        goals = obs["desired_goal"].reshape(n, 3)
        np.testing.assert_allclose(goals[:, :2], u.tray_centres)
        slots.add(tuple(np.argmin(np.abs(u.TRAY_SLOTS[:, 0][None] - goals[:, :1]), axis=1)))
        assert not u.is_success(obs["achieved_goal"], obs["desired_goal"])
    assert len(slots) == 2                                            # each colour's tray goes to either place
    e.close()


def test_pick_and_place_success_needs_every_jack_lying_in_its_tray():
    e = gym.make("SurRoL/PickAndPlace-v0")
    u = e.unwrapped
    goal = np.array([0.53, 0.03, 0.681, 0.57, 0.03, 0.681])
    inside = goal + [0.012, -0.012, 0.002, -0.005, 0.0, -0.002]
    one_out = inside + [0.0, 0.0, 0.0, 0.0, 0.0135, 0.0]              # second jack over the wall
    held_above = inside + [0.0, 0.0, 0.004, 0.0, 0.0, 0.0]           # first jack still held above its floor
    swapped = np.concatenate([goal[3:], goal[:3]])                    # each jack in the other colour's tray
    ag = np.stack([inside, one_out, held_above, swapped])
    np.testing.assert_array_equal(u.is_success(ag, np.repeat(goal[None], 4, axis=0)), [True, False, False, False])
    np.testing.assert_array_equal(u.in_tray(one_out, goal), [True, False])
    e.close()


def test_jack_dropped_over_a_tray_lands_in_it():
    e = gym.make("SurRoL/PickAndPlace-v0")
    u = e.unwrapped
    obs, _ = e.reset(seed=0)
    c, body = u.client, u.jacks[0]
    centre = u.tray_centres[0] + [0.006, -0.004]
    c.resetBasePositionAndOrientation(body, ((np.array([*centre, jacks.tray_wall_top_z() + 0.012])) * 5).tolist(),
                                      c.getQuaternionFromEuler([0.4, 0.2, 1.0]))
    c.changeDynamics(body, -1, activationState=physics.pb.ACTIVATION_STATE_WAKE_UP)
    for _ in range(3 * physics.SUBSTEPS * 5):   # 3 s
        c.stepSimulation()
    assert u.in_tray(u.achieved_goal(), u.goal)[0]
    e.close()


# ---------------------------------------------------------------------------------------------- MatchBoard
def test_match_board_glyphs_seat_only_the_right_way_round():
    names = list(mb.GLYPHS)
    for a in names:
        assert not any(mb.glyph_half_turn_fits(a, b) for b in names), a   # no half-turn fits any groove
        pixel, across = mb.grasp_pixel(a)
        assert across in (0.0, np.pi / 2)
    e = gym.make("SurRoL/MatchBoard-v0")
    u = e.unwrapped
    results = {}
    for seed in range(2):
        e.reset(seed=seed)
        c, g = u.client, u.board.groove_centre(u.glyph)
        for yaw_deg, dx in [(0.0, 0.0), (3.0, 0.0006), (15.0, 0.0), (90.0, 0.0), (180.0, 0.0)]:
            mb.place_block(c, u.object_id, u.glyph, g[:2] + [dx, 0.0], u.board.top_z + 0.001, np.deg2rad(yaw_deg))
            c.changeDynamics(u.object_id, -1, activationState=physics.pb.ACTIVATION_STATE_WAKE_UP)
            for _ in range(physics.SUBSTEPS * 10):   # 2 s
                c.stepSimulation()
            results[(u.glyph, yaw_deg)] = bool(u.is_success(u.achieved_goal(), g))
    for (glyph, yaw_deg), seated in results.items():
        assert seated == (yaw_deg < 10.0), (glyph, yaw_deg)
    e.close()


def test_match_board_draws_block_glyph_place_and_turn():
    e = gym.make("SurRoL/MatchBoard-v0")
    u = e.unwrapped
    glyphs, yaws = set(), []
    for seed in range(16):
        obs, _ = e.reset(seed=seed)
        glyphs.add(u.glyph)
        np.testing.assert_allclose(obs["desired_goal"], u.board.groove_centre(u.glyph))
        assert abs(obs["achieved_goal"][2] - (jacks.objects.TABLE_TOP_Z + mb.BLOCK_HEIGHT / 2)) < 1e-3   # lying flat
        yaws.append(obs["observation"][18])
        assert not u.is_success(obs["achieved_goal"], obs["desired_goal"])
    assert glyphs == set(mb.GLYPHS)
    assert max(np.abs(yaws)) > np.deg2rad(20) and max(np.abs(yaws)) <= u.BLOCK_YAW_RANGE + 1e-3
    e.close()


@pytest.mark.parametrize("episodes", [6, pytest.param(100, marks=pytest.mark.slow)])
@pytest.mark.parametrize("task", TASKS)
def test_oracle_success_rate(task, episodes):
    e = gym.make(f"SurRoL/{task}-v0")
    final = [run_oracle(e, seed).successes[-1] for seed in range(episodes)]
    assert np.mean(final) >= 0.95
    e.close()

"""The paper's single-arm training tasks (PickAndPlace, MatchBoard, MatchBoardPanel): Gymnasium API, goals and
success as the paper words them, the physics their success rests on, determinism and oracle success."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import drawer as dr
from surrol_data.envs import jacks, physics
from surrol_data.envs import match_board as mb

from oracle_episode import assert_same_episode, run_oracle, task_env_fixture

TASKS = ["PickAndPlace", "MatchBoard", "MatchBoardPanel"]
env = task_env_fixture(TASKS)


def test_check_env_passes(env):
    check_env(env.unwrapped, skip_render_check=True)


def test_equal_seeds_give_equal_episodes(env):
    first = run_oracle(env, seed=5, steps=40)
    # An interrupting episode that ends with the object in hand: nothing of it may leak into the next one.
    assert run_oracle(env, seed=6, steps=20).grasped[-1]
    assert_same_episode(first, run_oracle(env, seed=5, steps=40))
    a, b = env.reset(seed=5)[0], env.reset(seed=7)[0]
    assert not np.allclose(a["observation"], b["observation"])


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
    assert e.spec.max_episode_steps == 200
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
    for seed in range(12):
        e.reset(seed=seed)
        if any(glyph == u.glyph for glyph, _ in results):
            continue
        c, g = u.client, u.board.groove_centre(u.glyph)
        for yaw_deg, dx in [(0.0, 0.0), (5.0, 0.001), (20.0, 0.0), (90.0, 0.0), (180.0, 0.0)]:
            mb.place_block(c, u.object_id, u.glyph, g[:2] + [dx, 0.0], u.board.top_z + 0.001, np.deg2rad(yaw_deg))
            c.changeDynamics(u.object_id, -1, activationState=physics.pb.ACTIVATION_STATE_WAKE_UP)
            for _ in range(physics.SUBSTEPS * 10):   # 2 s
                c.stepSimulation()
            results[(u.glyph, yaw_deg)] = bool(u.is_success(u.achieved_goal(), g))
    assert {glyph for glyph, _ in results} == set(mb.GLYPHS)
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


# ---------------------------------------------------------------------------------------------- MatchBoardPanel
def test_panel_drawer_holds_by_friction_and_opens_only_to_its_stop():
    e = gym.make("SurRoL/MatchBoardPanel-v0")
    u = e.unwrapped
    obs, _ = e.reset(seed=0)
    c, d = u.client, u.drawer
    assert dr.opening(c, d) == pytest.approx(0.0, abs=1e-6)
    for force, steps, moves in ((0.5 * dr.FRICTION_N, physics.SUBSTEPS, False), (1.5 * dr.FRICTION_N, 3, True)):
        start = dr.opening(c, d)
        for _ in range(steps):   # a steady pull on the handle along the drawer's axis
            c.applyExternalForce(d, 0, [0.0, -force, 0.0], c.getLinkState(d, 0)[0], c.WORLD_FRAME)
            c.stepSimulation()
        assert (dr.opening(c, d) - start > 1e-3) == moves, force
    obs, _ = e.reset(seed=0)
    info = {"subtasks": {"open the drawer": False}}
    while not info["subtasks"]["open the drawer"]:   # the oracle grasps the handle and pulls the drawer open
        obs, *_, info = e.step(u.oracle_action(obs))
    assert info["subtasks"]["open the drawer"] and info["grasped"]
    for _ in range(3):                # pulling on at full speed: the stop holds the drawer
        obs, *_, info = e.step(np.array([0.0, -1.0, 0.0, 0.0, -1.0], np.float32))
        assert dr.opening(c, d) < dr.TRAVEL + 5e-4
    held = dr.opening(c, d)
    for _ in range(3):                # let go: it stays where it is
        obs, *_ = e.step(np.array([0.0, 0.0, 0.0, 0.0, 1.0], np.float32))
    assert dr.opening(c, d) == pytest.approx(held, abs=1e-4)
    e.close()


def test_panel_cells_are_covered_until_the_drawer_is_open():
    e = gym.make("SurRoL/MatchBoardPanel-v0")
    u = e.unwrapped
    obs, _ = e.reset(seed=1)
    assert obs["achieved_goal"].shape == (6,) and obs["observation"].shape == (23,)
    c = u.client
    closed_cell = u.cabinet.cell_floor_centre(u.target_cell, 0.0)
    mb.place_block(c, u.object_id, u.glyph, closed_cell[:2], u.cabinet.cover_top_z + 0.002, 0.0)
    c.changeDynamics(u.object_id, -1, activationState=physics.pb.ACTIVATION_STATE_WAKE_UP)
    obs, *_, info = e.step(np.array([0, 0, 0, 0, 1], np.float32))
    for _ in range(5):
        obs, *_, info = e.step(np.array([0, 0, 0, 0, 1], np.float32))
    assert obs["achieved_goal"][2] > u.cabinet.cover_top_z                  # lies on the cover, not in the cell
    assert info["subtasks"] == {"open the drawer": False, "place the block in the target cell": False}
    # Success needs both sub-tasks: the block in the open drawer's target cell, and the drawer open.
    goal = obs["desired_goal"].astype(np.float64)
    wrong_cell = goal.copy()
    wrong_cell[0] += dr.CELL_WIDTH + 0.001
    half_open = goal.copy()
    half_open[4] += 0.015
    ag = np.stack([goal, wrong_cell, half_open])
    np.testing.assert_array_equal(u.is_success(ag, np.repeat(goal[None], 3, axis=0)), [True, False, False])
    e.close()


def test_panel_subtasks_are_done_in_order_by_the_oracle():
    e = gym.make("SurRoL/MatchBoardPanel-v0")
    u = e.unwrapped
    obs, info = e.reset(seed=3)
    order = []
    for _ in range(e.spec.max_episode_steps):
        obs, *_, info = e.step(u.oracle_action(obs))
        done = tuple(info["subtasks"].values())
        if not order or order[-1] != done:
            order.append(done)
    assert order == [(False, False), (True, False), (True, True)]
    assert info["is_success"] == 1.0
    e.close()


# The oracle is done within these many steps (50, 35 and 59 on average); the slow test runs the whole horizon.
ORACLE_STEPS = {"PickAndPlace": 70, "MatchBoard": 50, "MatchBoardPanel": 75}


@pytest.mark.parametrize("episodes", [4, pytest.param(100, marks=pytest.mark.slow)])
@pytest.mark.parametrize("task", TASKS)
def test_oracle_success_rate(task, episodes):
    e = gym.make(f"SurRoL/{task}-v0")
    steps = ORACLE_STEPS[task] if episodes < 100 else None
    final = [run_oracle(e, seed, steps).successes[-1] for seed in range(episodes)]
    assert np.mean(final) >= 0.95
    e.close()


# ---------------------------------------------------------------------------------------------- simulated operators
def _operator_episode(task: str, skill: str, seed: int) -> bool:
    """A simulated operator through the haptic session's loop (frames → mapping → env), 3× the horizon."""
    from surrol_data.collect.mapping import ActionMapper, MappingSettings, view_to_action
    from surrol_data.collect.operator import SimulatedOperator

    env = gym.make(f"SurRoL/{task}-v0", max_episode_steps=3 * gym.spec(f"SurRoL/{task}-v0").max_episode_steps)
    op = SimulatedOperator(env.unwrapped, skill, f"{skill}-0", MappingSettings(), seed=0)
    op.connect()
    mapper = ActionMapper(op.mapping)
    obs, info = env.reset(seed=seed)
    for _ in range(env.spec.max_episode_steps):
        op.observe(obs, info)
        obs, _, _, truncated, info = env.step(mapper(op.read(), view_to_action(env)).arm)
        if info["is_success"] or truncated:
            break
    env.close()
    return bool(info["is_success"])


def test_simulated_expert_places_the_match_board_block():
    assert _operator_episode("MatchBoard", "expert", 1000)


@pytest.mark.slow
@pytest.mark.parametrize("skill", ["expert", "novice"])
@pytest.mark.parametrize("task", TASKS)
def test_simulated_operators_succeed(task, skill):
    # benchmarks/operator_tasks.py (10 episodes each): experts 9–10/10; novices 10/10, 6/10 (MatchBoard: a block
    # released more than ~8° off its groove rests on the edge, and the operator model does not re-grasp it) and 8/10.
    results = [_operator_episode(task, skill, 1000 + k) for k in range(4)]
    assert sum(results) >= (3 if skill == "expert" else 2), results


def test_drawer_friction_keeps_its_force_in_refined_steps():
    # The friction is a motor's force limit, which PyBullet fixes with the time step of the call: after the
    # adaptive sub-steps refine the step it must be re-issued, else the drawer holds k times harder.
    import pybullet as pb

    e = gym.make("SurRoL/MatchBoardPanel-v0")
    try:
        u = e.unwrapped
        e.reset(seed=0)
        u._set_time_step(physics.TIME_STEP / 8)
        start = dr.opening(u.client, u.drawer)
        for _ in range(8 * physics.SUBSTEPS):   # 0.2 s
            at = u.client.getLinkState(u.drawer, 0)[0]
            u.client.applyExternalForce(u.drawer, 0, (0.0, -3.0 * dr.FRICTION_N, 0.0), at, pb.WORLD_FRAME)
            u.client.stepSimulation()
        u._set_time_step(physics.TIME_STEP)
        assert dr.opening(u.client, u.drawer) - start > 1e-3   # three times its friction pulls it out
    finally:
        e.close()

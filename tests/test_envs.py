"""The PSM tasks: Gymnasium API, kinematics round trips, control limits, contacts and oracle success."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import kinematics as kin
from surrol_data.envs import physics
from surrol_data.envs.psm import JAW_JOINTS
from surrol_data.envs.psm_env import tool_down
from surrol_data.envs.units import CONTROL_PERIOD_S, SCALING

from oracle_episode import assert_same_episode, run_oracle, task_env_fixture

TASKS = ["NeedleReach", "NeedlePick"]
env = task_env_fixture(TASKS)



def test_check_env_passes(env):
    check_env(env.unwrapped, skip_render_check=True)


def test_spaces_and_defaults(env):
    assert env.spec.max_episode_steps == 50
    assert env.action_space.shape == (5,)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    assert all(v.dtype == np.float32 for v in obs.values())
    assert obs["observation"].shape == env.observation_space["observation"].shape
    assert info["tip_position"].shape == (1, 3) and info["jaw_angle"].shape == (1,)


def test_max_episode_steps_overridable():
    e = gym.make("SurRoL/NeedleReach-v0", max_episode_steps=7)
    e.reset(seed=0)
    for t in range(7):
        *_, truncated, _ = e.step(e.action_space.sample())
    assert truncated
    e.close()


def test_equal_seeds_give_equal_episodes(env):
    first = run_oracle(env, seed=11, steps=40)
    run_oracle(env, seed=12, steps=10)
    assert_same_episode(first, run_oracle(env, seed=11, steps=40))
    goal_11 = env.reset(seed=11)[0]["desired_goal"]
    goal_13 = env.reset(seed=13)[0]["desired_goal"]
    assert not np.allclose(goal_11, goal_13)


def test_compute_reward_is_batched_and_matches_info(env):
    obs, info = env.reset(seed=3)
    u = env.unwrapped
    ag = np.stack([obs["desired_goal"], obs["desired_goal"] + [0.0, 0.0, 0.004], obs["desired_goal"] + 0.01])
    dg = np.repeat(obs["desired_goal"][None], 3, axis=0)
    np.testing.assert_array_equal(u.compute_reward(ag, dg, None), [0.0, 0.0, -1.0])
    obs, reward, *_, info = env.step(np.zeros(5, np.float32))
    assert reward == info["is_success"] - 1.0


@settings(max_examples=300, deadline=None)
@given(st.tuples(*[st.floats(float(lo), float(hi)) for lo, hi in zip(kin.PSM_LOWER, kin.PSM_UPPER)]))
def test_ik_inverts_fk_over_the_joint_space(q):
    q = np.array(q)
    q[2] = max(q[2], 0.03)  # the wrist must be past the RCM (inserted) for the natural solution to exist
    pose = kin.psm_fk(q)
    sol = kin.psm_ik(pose)
    back = kin.psm_fk(sol.q)
    assert np.linalg.norm(back[:3, 3] - pose[:3, 3]) < 1e-4  # < 0.1 mm
    np.testing.assert_allclose(back[:3, :3], pose[:3, :3], atol=1e-6)


def test_simulated_tip_matches_kinematics(env):
    u = env.unwrapped
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    from surrol_data.envs.psm import TIP_LINK
    pos, rot = u.psm.link_pose_world(TIP_LINK)
    pose = u.psm.tip_pose()
    assert np.linalg.norm(pos - pose[:3, 3]) < 1e-6
    np.testing.assert_allclose(rot, pose[:3, :3], atol=1e-5)


def test_large_tip_command_respects_velocity_limits():
    e = gym.make("SurRoL/NeedleReach-v0")
    u = e.unwrapped
    e.reset(seed=0)
    start = u.psm.tip_pose()[:3, 3].copy()
    target = start + np.array([0.06, -0.06, -0.05])  # ~10 cm away, straight to the arm (no action clipping)
    assert np.linalg.norm(target - start) > 0.095
    assert u.psm.command_tip(kin.pose_from(target, tool_down(0.0)))
    vmax = np.array(physics.PSM_MAX_VELOCITY)
    positions = [start]
    for _ in range(40):
        for _ in range(physics.SUBSTEPS):
            u.client.stepSimulation()
            assert np.all(np.abs(u.psm.joint_velocities()) <= vmax * 1.02 + 1e-6)
        positions.append(u.psm.tip_pose()[:3, 3].copy())
    positions = np.array(positions)
    step_moves = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    # The tip speed is bounded by the joint speed limits times the lever arms (< 0.25 m from the RCM).
    bound = (vmax[0] + vmax[1]) * 0.25 * CONTROL_PERIOD_S + vmax[2] * CONTROL_PERIOD_S
    assert step_moves.max() <= bound
    assert step_moves[0] < 0.5 * np.linalg.norm(target - start)  # no teleporting
    assert np.linalg.norm(positions[-1] - target) < 1e-3          # but it gets there
    e.close()


def _deepest_penetration_m(client, body_a, body_b) -> float:
    pts = client.getContactPoints(body_a, body_b)
    return -min([p[8] for p in pts], default=0.0) / SCALING


def test_pushing_jaw_into_needle_and_table_stays_shallow():
    e = gym.make("SurRoL/NeedlePick-v0")
    u = e.unwrapped
    obs, _ = e.reset(seed=1)
    wp = u.needle_waypoint(1)
    # Over the needle with the jaw closed, then full-speed pushes down into needle, pad and table.
    for _ in range(20):
        err = (wp + [0.0, 0.0, 0.01] - obs["observation"][:3]) / 0.01
        obs, *_ = e.step(np.array([*np.clip(err, -1, 1), 0.0, -1.0], np.float32))
    worst = [0.0]

    def probe(env):
        for body in range(env.client.getNumBodies()):
            if body != env.psm.body:
                worst[0] = max(worst[0], _deepest_penetration_m(env.client, env.psm.body, body))

    u.substep_hook = probe
    for _ in range(6):
        e.step(np.array([0.0, 0.0, -1.0, 0.0, -1.0], np.float32))
    u.substep_hook = None
    assert worst[0] < 1e-3, f"jaw penetrated {worst[0] * 1000:.2f} mm"
    e.close()


def test_grasp_attaches_only_when_both_jaws_touch():
    e = gym.make("SurRoL/NeedlePick-v0")
    u = e.unwrapped
    obs, _ = e.reset(seed=2)
    closed_far = np.array([0, 0, 0, 0, -1], np.float32)
    obs, *_, info = e.step(closed_far)  # closing in mid-air grasps nothing
    assert not info["grasped"]
    grasped_at = None
    obs, _ = e.reset(seed=2)
    for t in range(50):
        obs, _, _, _, info = e.step(u.oracle_action(obs))
        if info["grasped"] and grasped_at is None:
            grasped_at = t
            touching = [bool(u.client.getClosestPoints(u.psm.body, u.object_id, 0.01, linkIndexA=j)) for j in JAW_JOINTS]
            assert all(touching)
    assert grasped_at is not None
    # Opening the jaw releases the needle, which then falls back towards the pad.
    obs, *_, info = e.step(np.array([0, 0, 0, 0, 1], np.float32))
    assert not info["grasped"]
    z0 = obs["achieved_goal"][2]
    for _ in range(5):
        obs, *_ = e.step(np.array([0, 0, 0, 0, 1], np.float32))
    assert obs["achieved_goal"][2] < z0 - 0.005
    e.close()


@pytest.mark.parametrize("episodes", [30, pytest.param(200, marks=pytest.mark.slow)])
@pytest.mark.parametrize("task", TASKS)
def test_oracle_success_rate(task, episodes):
    e = gym.make(f"SurRoL/{task}-v0")
    results = [run_oracle(e, seed).successes[-1] for seed in range(episodes)]
    assert np.mean(results) >= 0.99
    e.close()


def test_tasks_command_lists_every_task_with_its_sizes():
    from typer.testing import CliRunner

    from surrol_data.cli import app

    result = CliRunner().invoke(app, ["tasks"], terminal_width=120)
    assert result.exit_code == 0, result.output
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
            for line in result.output.splitlines() if line.startswith("│")}
    assert set(rows) == set(surrol_data.envs.TASKS)
    assert rows["NeedlePick"] == ["PSM", "19", "3", "5", "50"]
    assert rows["BiPegTransfer"] == ["PSM×2", "35", "3", "10", "50"]
    assert rows["MisOrient"] == ["ECM", "9", "1", "1", "50"]
    assert rows["ActiveTrack"][-1] == "500"


def test_euler_xyz_matches_pybullet():
    from surrol_data.envs.physics import pb
    from surrol_data.envs.psm import matrix_to_quat

    rng = np.random.default_rng(0)
    for _ in range(20):
        angles = rng.uniform([-np.pi, -1.4, -np.pi], [np.pi, 1.4, np.pi])
        rot = np.asarray(pb.getMatrixFromQuaternion(pb.getQuaternionFromEuler(angles.tolist()))).reshape(3, 3)
        np.testing.assert_allclose(kin.euler_xyz(rot), angles, atol=1e-9)
        np.testing.assert_allclose(kin.euler_xyz(rot), pb.getEulerFromQuaternion(matrix_to_quat(rot)), atol=1e-9)

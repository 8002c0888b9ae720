"""The ECM, its camera and the four ECM tasks: kinematics, motor law, camera geometry, Gymnasium API,
determinism and oracle success against the reference's numbers."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import ecm_kinematics as ekin
from surrol_data.envs import kinematics as psm_kin
from surrol_data.envs import physics
from surrol_data.envs.camera import pixel_of, project
from surrol_data.envs.ecm import pd_with_limits
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import matrix_to_quat

from oracle_episode import assert_same_episode, run_oracle

TASKS = ["ECMReach", "MisOrient", "StaticTrack", "ActiveTrack"]
# Final-step oracle success: ≥ 99 % (issue 11); the reference reaches 0.98, 0.88 and 0.94 (50 episodes).
ACTIVE_TRACK_REFERENCE_RETURN = 484.0





# ---------------------------------------------------------------------------------------------- kinematics
@settings(max_examples=300, deadline=None)
@given(st.tuples(*[st.floats(float(lo), float(hi)) for lo, hi in zip(ekin.ECM_LOWER, ekin.ECM_UPPER)]))
def test_ik_inverts_fk_over_the_joint_space(q):
    q = np.array(q)
    q[2] = max(q[2], 0.005)   # the EEF must be beyond the RCM for the view direction to be defined
    pose = ekin.ecm_fk(q)
    np.testing.assert_allclose(pose, ekin.ecm_fk_dh(q), atol=1e-12)   # the closed form is the DH product
    sol = ekin.ecm_ik(pose)
    assert sol.within_limits
    back = ekin.ecm_fk(sol.q)
    assert np.linalg.norm(back[:3, 3] - pose[:3, 3]) < 1e-4          # < 0.1 mm
    np.testing.assert_allclose(back[:3, :3], pose[:3, :3], atol=1e-9)


def test_zero_joints_point_down_the_rcm_frame_and_ik_refuses_the_rcm():
    pose = ekin.ecm_fk([0.0, 0.0, 0.1, 0.0])
    np.testing.assert_allclose(pose[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [0, 0, -(0.1 + ekin.INSERTION_OFFSET_M)], atol=1e-12)
    with pytest.raises(ValueError, match="RCM"):
        ekin.ecm_ik_position([0.0, 0.0, 0.0], 0.0)


def _pybullet_chain(client) -> int:
    """The ECM's four DH joints as a PyBullet multibody (no collision shapes), to drive with its own motors."""
    positions, orientations, types = [], [], []
    for row in ekin.ECM_DH:
        fixed = psm_kin.dh_fixed_transform(row)
        positions.append(fixed[:3, 3].tolist())
        orientations.append(matrix_to_quat(fixed[:3, :3]))
        types.append(pb.JOINT_PRISMATIC if row[4] else pb.JOINT_REVOLUTE)
    n = len(types)
    body = client.createMultiBody(
        baseMass=0.0, basePosition=[0, 0, 1], linkMasses=[0.5] * n, linkCollisionShapeIndices=[-1] * n,
        linkVisualShapeIndices=[-1] * n, linkPositions=positions, linkOrientations=orientations,
        linkInertialFramePositions=[[0, 0, 0]] * n, linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
        linkParentIndices=list(range(n)), linkJointTypes=types, linkJointAxis=[[0, 0, 1]] * n)
    for j in range(n):
        client.changeDynamics(body, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0,
                              localInertiaDiagonal=[0.01] * 3)
    return body


def test_closed_form_motion_matches_pybullets_position_motor():
    """The closed form integrates PyBullet's motor law; compare it with PyBullet driving a real chain."""
    client = physics.make_client()
    client.setPhysicsEngineParameter(fixedTimeStep=physics.ECM_CONTROL_PERIOD_S / physics.ECM_SUBSTEPS)
    body = _pybullet_chain(client)
    start = [0.1, -0.2, 0.05, 0.3]
    target = [0.5, 0.3, 0.15, -0.9]          # large enough that the velocity limits bind for a while
    for j, v in enumerate(start):
        client.resetJointState(body, j, v, 0.0)
    dt = physics.ECM_CONTROL_PERIOD_S / physics.ECM_SUBSTEPS
    for j, v in enumerate(target):
        client.setJointMotorControl2(body, j, pb.POSITION_CONTROL, targetPosition=v, targetVelocity=0.0,
                                     positionGain=physics.ECM_POSITION_GAIN, velocityGain=1.0, force=1e5,
                                     maxVelocity=physics.ECM_MAX_VELOCITY[j])
    q = list(start)
    for period in range(8):
        for _ in range(physics.ECM_SUBSTEPS):
            client.stepSimulation()
        q = [pd_with_limits(qi, ti, physics.ECM_POSITION_GAIN, vmax * dt, physics.ECM_SUBSTEPS)
             for qi, ti, vmax in zip(q, target, physics.ECM_MAX_VELOCITY)]
        simulated = [s[0] for s in client.getJointStates(body, range(4))]
        np.testing.assert_allclose(q, simulated, atol=2e-3, err_msg=f"after {period + 1} control periods")
    client.disconnect()


def test_pd_with_limits_is_bounded_and_converges():
    q, speeds = 0.0, []
    for _ in range(30):
        new = pd_with_limits(q, 1.0, 0.1, 0.004, 24)
        speeds.append(new - q)
        q = new
    assert max(speeds) <= 24 * 0.004 + 1e-12          # velocity limit
    assert abs(q - 1.0) < 1e-3 and all(s >= 0 for s in speeds)   # gets there without overshoot


# ---------------------------------------------------------------------------------------------- camera
def test_camera_sees_the_target_where_it_is_projected_with_depth_and_light():
    env = gym.make("SurRoL/StaticTrack-v0", camera=True, camera_size=(160, 120))
    u = env.unwrapped
    obs, _ = env.reset(seed=1)
    for _ in range(30):   # bring the cube near the image centre
        obs, *_ = env.step(u.oracle_action(obs))
    assert obs["image"].shape == (120, 160, 3) and obs["image"].dtype == np.uint8
    img = u.render_endoscope(size=(256, 256), depth=True, segmentation=True)
    mask = img.segmentation == u.target_id
    assert mask.sum() > 200
    rows, cols = np.nonzero(mask)
    col, row = pixel_of(project(u.ecm.camera_axes(), u.target_position)[:2], 256, 256)
    assert abs(cols.mean() - col) < 3 and abs(rows.mean() - row) < 3
    # Depth at the cube is its distance along the view axis minus (about) half its size: the face it shows.
    depth_centre = project(u.ecm.camera_axes(), u.target_position)[2]
    seen = float(np.median(img.depth[mask]))
    assert depth_centre - 0.07 < seen < depth_centre
    # The red cube is red, and the light comes from the endoscope: the top face it looks at is bright.
    r, g, b = img.rgb[mask].astype(float).mean(axis=0)
    assert r > 120 and r > 2 * g and r > 1.2 * b
    env.close()


def test_camera_off_builds_nothing_visual_and_adds_no_image():
    env = gym.make("SurRoL/StaticTrack-v0")
    obs, _ = env.reset(seed=0)
    assert "image" not in obs and not env.unwrapped.visual


def test_bad_camera_size_is_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="camera_size"):
        gym.make("SurRoL/ECMReach-v0", camera=True, camera_size=(0, 10))


# ---------------------------------------------------------------------------------------------- Gymnasium API
@pytest.mark.parametrize("task", TASKS)
def test_check_env_passes(task):
    env = gym.make(f"SurRoL/{task}-v0")
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert all(obs[k].dtype == np.float32 for k in ("observation", "achieved_goal", "desired_goal"))
    assert info["tip_position"].shape == (1, 3) and info["tip_position"].dtype == np.float32
    assert info["jaw_angle"].shape == (1,)
    assert env.spec.max_episode_steps == (500 if task == "ActiveTrack" else 50)
    env.close()


@pytest.mark.parametrize("task", ["ECMReach", "NeedleReach"])
def test_check_env_passes_with_the_endoscope_image(task):
    env = gym.make(f"SurRoL/{task}-v0", camera=True, camera_size=(64, 48))
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs["image"].shape == (48, 64, 3) and obs["image"].dtype == np.uint8
    assert obs["image"].std() > 5   # an actual view, not a blank frame
    env.close()


@pytest.mark.parametrize("task", TASKS)
def test_equal_seeds_give_equal_episodes(task):
    env = gym.make(f"SurRoL/{task}-v0")
    first = run_oracle(env, seed=11, steps=40)
    run_oracle(env, seed=12, steps=10)
    assert_same_episode(first, run_oracle(env, seed=11, steps=40))
    assert not np.array_equal(env.reset(seed=11)[0]["observation"], env.reset(seed=13)[0]["observation"]) \
        or not np.array_equal(env.reset(seed=11)[0]["desired_goal"], env.reset(seed=13)[0]["desired_goal"])
    env.close()


def test_ecm_reach_action_moves_the_eef_one_centimetre_in_the_rcm_frame():
    env = gym.make("SurRoL/ECMReach-v0")
    u = env.unwrapped
    env.reset(seed=0)
    start = np.array(u.ecm.world_to_rcm(u.ecm.eef_position_world()))
    env.step(np.array([0, 0, 1.0], np.float32))
    moved = np.array(u.ecm.world_to_rcm(u.ecm.eef_position_world())) - start
    # One step of the PD motor closes 1 − 0.9²⁴ ≈ 92 % of the commanded 1 cm, along the RCM frame's z.
    np.testing.assert_allclose(moved, [0, 0, 0.01 * (1 - 0.9 ** 24)], atol=2e-4)
    env.close()


def test_sparse_rewards_are_batched_and_match_info():
    env = gym.make("SurRoL/ECMReach-v0")
    u = env.unwrapped
    obs, _ = env.reset(seed=3)
    dg = np.repeat(obs["desired_goal"][None], 3, axis=0)
    ag = dg + np.array([[0, 0, 0], [0, 0, 0.004], [0.01, 0, 0]], np.float32)
    np.testing.assert_array_equal(u.compute_reward(ag, dg, None), [0.0, 0.0, -1.0])
    obs, reward, *_, info = env.step(np.zeros(3, np.float32))
    assert reward == info["is_success"] - 1.0
    env.close()


def test_active_track_reward_is_dense_batched_and_the_episode_ends_out_of_view():
    env = gym.make("SurRoL/ActiveTrack-v0")
    u = env.unwrapped
    obs, _ = env.reset(seed=0)
    ag = np.array([[0, 0, 0], [0.2, 0, 0], [0, 0, 1.0], [1.5, 0, 0]], np.float32)
    np.testing.assert_allclose(u.compute_reward(ag, np.zeros((4, 3), np.float32)), [1.0, 0.9, 0.9, 0.25], atol=1e-6)
    np.testing.assert_array_equal(u.is_success(ag, np.zeros((4, 3))), [True, True, True, False])
    terminated = False
    for t in range(200):  # swing the view away as fast as possible: the cube must leave the image
        obs, reward, terminated, truncated, info = env.step(np.array([1.0, 1.0, 0.0], np.float32))
        assert np.isclose(reward, u.compute_reward(obs["achieved_goal"], obs["desired_goal"]))
        if terminated:
            break
    assert terminated and info["is_success"] == 0.0
    env.close()


def test_mis_orient_roll_undoes_the_misorientation():
    env = gym.make("SurRoL/MisOrient-v0")
    u = env.unwrapped
    obs, _ = env.reset(seed=5)
    before = float(obs["achieved_goal"][0])
    obs, *_ = env.step(np.array([np.sign(before)], np.float32))
    # Rolling by +3° moves the misorientation by about −3° (the image turns with the roll).
    assert abs(float(obs["achieved_goal"][0])) < abs(before)
    assert u.ecm.q[3] != 0.0
    env.close()


# ---------------------------------------------------------------------------------------------- oracles
def _oracle_rate(task, episodes):
    env = gym.make(f"SurRoL/{task}-v0")
    finals, returns, lengths = [], [], []
    for seed in range(episodes):
        episode = run_oracle(env, seed)
        rewards, successes = episode.rewards, episode.successes
        finals.append(successes[-1])
        returns.append(rewards.sum())
        lengths.append(len(rewards))
    env.close()
    return np.mean(finals), np.mean(returns), min(lengths)


@pytest.mark.parametrize("episodes", [20, pytest.param(100, marks=pytest.mark.slow)])
@pytest.mark.parametrize("task", ["ECMReach", "MisOrient", "StaticTrack"])
def test_oracle_success_rate(task, episodes):
    success, _, _ = _oracle_rate(task, episodes)
    assert success >= 0.99   # issue 11: every oracle ≥ 99 % (the reference's own may be lower)


@pytest.mark.parametrize("episodes", [3, pytest.param(100, marks=pytest.mark.slow)])
def test_active_track_oracle_keeps_the_target_in_view(episodes):
    in_view_all, mean_return, shortest = _oracle_rate("ActiveTrack", episodes)
    assert shortest == 500 and in_view_all == 1.0
    assert mean_return >= ACTIVE_TRACK_REFERENCE_RETURN
    assert math.isfinite(mean_return)

"""Physical realism under rough input: grasps need the object between the blades, no tunnelling, the jaws stop
on what they hold, a yanked object drops, and actions are tracked. The 30-episode campaigns are in
``benchmarks/physics_realism.py``; the slow tests here run a share of them."""

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import objects, physics
from surrol_data.envs.units import SCALING

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import physics_realism  # noqa: E402


def _drive_to(env, target, jaw: float, steps: int = 25, gain: float = 0.6):
    """Proportional actions towards ``target`` (tip position, metres) with the given jaw command."""
    obs = None
    for _ in range(steps):
        tip = env.unwrapped.tip_pose()[:3, 3]
        err = (np.asarray(target) - tip) / 0.01
        if np.linalg.norm(err) < 0.03:
            break
        obs, *_ = env.step(np.array([*np.clip(err, -gain, gain), 0.0, jaw], np.float32))
    return obs


class DeepestOverlap:
    """A substep hook recording the deepest overlap (real metres) between two groups of bodies."""

    def __init__(self, group_a, group_b):
        self.pairs = [(a, b) for a in group_a for b in group_b if a != b]
        self.deepest = 0.0

    def __call__(self, env):
        for a, b in self.pairs:
            for p in env.client.getClosestPoints(a, b, 0.0):
                self.deepest = max(self.deepest, -p[8] / SCALING)


@pytest.fixture
def needle_pick():
    e = gym.make("SurRoL/NeedlePick-v0")
    yield e
    e.close()


def test_closed_jaw_poked_onto_the_needle_does_not_grasp_it(needle_pick):
    e, u = needle_pick, needle_pick.unwrapped
    e.reset(seed=3)
    wp = u.needle_waypoint(1)
    _drive_to(e, wp + [0.0, 0.0, 0.01], jaw=-1.0)
    for _ in range(4):
        *_, info = e.step(np.array([0.0, 0.0, -1.0, 0.0, -1.0], np.float32))
        assert not info["grasped"]
    for _ in range(3):
        *_, info = e.step(np.array([0.0, 0.0, 1.0, 0.0, -1.0], np.float32))
        assert not info["grasped"]
    assert u.needle_waypoint(1)[2] < objects.PAD_TOP_Z + 0.003   # the needle stayed down


@pytest.mark.parametrize("across_blades", [True, False])
def test_closed_jaw_swiped_into_the_needle_does_not_grasp_it(needle_pick, across_blades):
    e, u = needle_pick, needle_pick.unwrapped
    obs, _ = e.reset(seed=4)
    wp = u.needle_waypoint(1)
    _, rot = objects.needle_pose(u.client, u.object_id)
    # Jaw opening direction along the needle's x axis (as for a grasp); swipe along it or along the blades' width.
    yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
    opening = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    direction = opening if across_blades else np.array([-opening[1], opening[0], 0.0])
    start = wp + 0.006 * direction
    _drive_to(e, start + [0.0, 0.0, 0.012], jaw=-1.0)
    _drive_to(e, start - [0.0, 0.0, 0.001], jaw=-1.0, gain=0.3)
    for _ in range(3):
        *_, info = e.step(np.array([*(-direction[:2]), 0.0, 0.0, -1.0], np.float32))
        assert not info["grasped"]


def test_oracle_grasp_holds_the_needle_between_the_blades_and_the_jaw_reads_its_width(needle_pick):
    e, u = needle_pick, needle_pick.unwrapped
    obs, info = e.reset(seed=5)
    overlap = DeepestOverlap([u.psm.body], [u.object_id])
    u.substep_hook = overlap
    for _ in range(50):
        obs, _, _, _, info = e.step(u.oracle_action(obs))
        if info["grasped"]:
            break
    assert info["grasped"]
    assert physics_realism.between_blades(u.client, u.psm.body, u.object_id)
    for _ in range(3):
        obs, _, _, _, info = e.step(u.oracle_action(obs))
    u.substep_hook = None
    # The blades stopped on the 1.24 mm wire: the jaw stays open by about the wire's angle at the blade end.
    wire_angle = 2 * np.arcsin(objects.NEEDLE_WIRE_RADIUS / physics.BLADE_LENGTH_M)
    assert info["jaw_angle"][0] > 0.5 * wire_angle
    assert overlap.deepest < 1e-3


def test_gauze_held_by_the_oracle_keeps_the_jaw_open_by_its_width():
    e = gym.make("SurRoL/GauzeRetrieve-v0")
    u = e.unwrapped
    obs, info = e.reset(seed=0)
    for _ in range(50):
        obs, _, _, _, info = e.step(u.oracle_action(obs))
        if u.grasp.welded:
            break
    assert u.grasp.welded
    # The 4 mm gauze between 10.2 mm blades: about 2·asin(2/10.2) ≈ 23° (less where it sits deeper).
    assert np.deg2rad(12.0) < info["jaw_angle"][0] < np.deg2rad(35.0)
    e.close()


def test_yanking_a_held_needle_past_the_weld_force_drops_it_and_counts_the_drop(needle_pick):
    e, u = needle_pick, needle_pick.unwrapped
    obs, info = e.reset(seed=6)
    for _ in range(50):
        obs, _, _, _, info = e.step(u.oracle_action(obs))
        if u.grasp.welded:
            break
    assert u.grasp.welded and info["drops"] == 0
    # Something pulls the needle out of the hand harder than the weld holds (the force-limited arm itself cannot:
    # it stalls first), for as long as it is held.
    c = u.client
    pull = [0.0, 0.0, 2.0 * physics.GRASP_MAX_FORCE]

    def pull_while_held(env):
        if env.grasp.attached:
            pos = c.getBasePositionAndOrientation(env.object_id)[0]
            c.applyExternalForce(env.object_id, -1, pull, pos, c.WORLD_FRAME)

    u.substep_hook = pull_while_held
    for _ in range(5):
        obs, _, _, _, info = e.step(np.array([0.0, 0.0, 0.0, 0.0, -1.0], np.float32))
        if not info["grasped"]:
            break
    u.substep_hook = None
    assert not info["grasped"]
    assert info["drops"] == 1


def _throw_needle(env, height_m: float, euler, velocity=(0.0, 0.0, 0.0), spin=(0.0, 0.0, 0.0), steps: int = 12):
    """Put the needle ``height_m`` above the pad in the pose ``euler`` with the given velocity (real m/s) and spin
    (rad/s), let it fall for ``steps`` control steps, and return its deepest overlap with any static body (real m)."""
    u = env.unwrapped
    c = u.client
    pos = np.asarray(c.getBasePositionAndOrientation(u.object_id)[0]) / SCALING
    pos[2] = objects.PAD_TOP_Z + height_m
    c.resetBasePositionAndOrientation(u.object_id, (pos * SCALING).tolist(), c.getQuaternionFromEuler(euler))
    c.resetBaseVelocity(u.object_id, (np.asarray(velocity) * SCALING).tolist(), list(spin))
    c.changeDynamics(u.object_id, -1, activationState=c.ACTIVATION_STATE_WAKE_UP)
    statics = [b for b in range(c.getNumBodies()) if b not in (u.psm.body, u.object_id, u.goal_marker)]
    overlap = DeepestOverlap([u.object_id], statics)
    u.substep_hook = overlap
    for _ in range(steps):
        env.step(np.array([0.0, 0.0, 0.0, 0.0, 1.0], np.float32))
    u.substep_hook = None
    return overlap.deepest


def test_a_needle_dropped_from_60_mm_lands_on_the_pad(needle_pick):
    e, u = needle_pick, needle_pick.unwrapped
    e.reset(seed=7)
    deepest = _throw_needle(e, 0.003 + 0.06, [0.4, 0.3, 1.0])
    rest = np.asarray(u.client.getBasePositionAndOrientation(u.object_id)[0]) / SCALING
    assert rest[2] > objects.PAD_TOP_Z                     # above the pad, not in or under it
    assert deepest < 1e-3


def test_a_spinning_needle_lands_on_the_pad_without_sinking_in(needle_pick):
    """A needle flicked by a poke tumbles; its ends move several times faster than its centre of mass, and the
    adaptive sub-steps must refine for them (they sank 1.9–2.2 mm into the pad when only the centre's speed counted)."""
    worst = 0.0
    for seed in range(4):
        needle_pick.reset(seed=seed)
        worst = max(worst, _throw_needle(needle_pick, 0.02, [0.3 * seed, 0.2, 1.0], velocity=(0.0, 0.0, -0.05),
                                         spin=(20.0, 8.0 * (seed % 2 - 0.5), 0.0), steps=4))
    assert worst < 1e-3, f"a spinning needle sank {1000 * worst:.2f} mm into the pad"


@pytest.mark.parametrize("action", [(1.0, -1.0, 1.0), (-1.0, 0.0, -1.0), (0.3, 0.7, -0.5)])
def test_actions_are_tracked_within_10_percent_in_free_space(needle_pick, action):
    e, u = needle_pick, needle_pick.unwrapped
    e.reset(seed=0)
    _drive_to(e, [0.55, 0.0, 0.725], jaw=1.0, gain=1.0)
    want = np.asarray(action) * 0.01
    for _ in range(2):
        before = u.tip_pose()[:3, 3].copy()
        e.step(np.array([*action, 0.0, 1.0], np.float32))
        moved = u.tip_pose()[:3, 3] - before
        assert np.linalg.norm(moved - want) <= 0.1 * np.linalg.norm(want)


def test_joint_motors_never_push_harder_than_their_limit_even_in_refined_steps(needle_pick):
    """A closed jaw driven down onto the pad at full speed: the adaptive sub-steps refine the step near the pad,
    and the motors' force limits must hold in those finer steps too (PyBullet converts a limit into an impulse
    with the step current when the command is given)."""
    e, u = needle_pick, needle_pick.unwrapped
    e.reset(seed=3)
    limits = np.array(physics.PSM_MAX_FORCE)
    worst = []

    def record(env):
        applied = np.array([s[3] for s in env.client.getJointStates(env.psm.body, range(6))])
        worst.append(float(np.max(np.abs(applied) / limits)))

    _drive_to(e, u.needle_waypoint(1) + [0.0, 0.0, 0.01], jaw=-1.0)
    u.substep_hook = record
    refined = u._substeps.refined_steps
    for _ in range(4):
        e.step(np.array([0.0, 0.0, -1.0, 0.0, -1.0], np.float32))
    u.substep_hook = None
    assert u._substeps.refined_steps > refined      # the press was refined
    assert max(worst) <= 1.0 + 1e-6


def test_a_block_poked_by_a_closed_jaw_stays_out_of_the_board():
    # The force-limited tool stalls on the block, and the contact solver holds it out of the board (8.6 mm with the
    # old 60 N·m motors, when 21 of 30 pokes left it inside the board; 1.5 mm with PyBullet's default solver).
    r = physics_realism.run_poke_swipe("PegTransfer", "poke", episodes=2)
    assert r.overlap["object-static"] <= 1e-3 and r.left_inside == 0


def test_a_grasp_holds_each_blade_where_it_stopped():
    """A jaw closed on a block wall 2 mm off its centre line meets the wall with one blade first, which is held back
    while the other closes: the blades grip turned together about the wrist. Held only by their opening angle, they
    swung back to symmetric after the grip, into the block (which no longer collides with them) and off it (under
    bang-bang input the benchmark's check then found a block no longer between the blades)."""
    e = gym.make("SurRoL/PegTransfer-v0")
    u = e.unwrapped
    skews = []
    for seed in range(3):
        obs, _ = e.reset(seed=seed)
        plan = u.oracle_waypoints
        close = next(k for k, wp in enumerate(plan) if wp["jaw"] < 0)
        while u._wp_index < close:                      # the oracle's approach, jaw open
            obs, *_ = e.step(u.oracle_action(obs))
        opening = u.tip_pose()[:3, 1]                    # the tip frame's y: the jaw-opening direction
        _drive_to(e, plan[close]["target"] + 0.002 * opening, jaw=1.0, steps=10, gain=0.5)
        stopped = None
        for _ in range(4):                               # close, then keep the jaw commanded closed
            *_, info = e.step(np.array([0.0, 0.0, 0.0, 0.0, -1.0], np.float32))
            blades = np.array([s[0] for s in u.client.getJointStates(u.psm.body, (6, 7))])
            if info["grasped"] and stopped is None:
                stopped = blades
        assert stopped is not None, f"seed {seed}: the off-centre jaw did not grip the wall"
        skews.append(abs(stopped[0] + stopped[1]))       # a symmetric jaw's blades sum to 0
        assert np.allclose(blades, stopped, atol=np.deg2rad(0.3)), np.rad2deg(blades - stopped)
        assert physics_realism.between_blades(u.client, u.psm.body, u.object_id)
    assert max(skews) > np.deg2rad(1.0)                  # the grips were skewed: the case this test is about
    e.close()


def test_reference_base_placement_is_consistent_and_keeps_commands_cartesian():
    """The reference puts PSM1's base at (0.05, 0.24, 0.8524) yawed −110° and PSM2's at (0.05, −0.24, 0.8524) yawed
    −70°, each RCM 0.4864 m along its base's y axis: the RCM points are ours, and an arm built with that yaw puts its
    tip where it is commanded; the envs build their arms with it (``psm_env.USE_REFERENCE_BASE_YAW``)."""
    from surrol_data.envs import kinematics as kin
    from surrol_data.envs.bimanual_env import PSM2_RCM
    from surrol_data.envs.psm import Psm
    from surrol_data.envs.psm_env import (PSM1_BASE_YAW_RAD, PSM1_RCM, REFERENCE_PSM1_BASE_YAW_RAD,
                                          REFERENCE_PSM2_BASE_YAW_RAD, USE_REFERENCE_BASE_YAW, tool_down)

    for base, yaw_deg, rcm, yaw in (((0.05, 0.24, 0.8524), -110.0, PSM1_RCM, REFERENCE_PSM1_BASE_YAW_RAD),
                                    ((0.05, -0.24, 0.8524), -70.0, PSM2_RCM, REFERENCE_PSM2_BASE_YAW_RAD)):
        rot = kin.rot_z3(np.deg2rad(yaw_deg))
        assert np.allclose(np.asarray(base) + rot @ [0.0, 0.4864, 0.0], rcm, atol=1e-3)
        assert yaw == pytest.approx(np.deg2rad(yaw_deg))
    assert USE_REFERENCE_BASE_YAW and PSM1_BASE_YAW_RAD == REFERENCE_PSM1_BASE_YAW_RAD
    for task, yaws in (("NeedlePick", (-110.0,)), ("BiPegTransfer", (-110.0, -70.0))):
        env = gym.make(f"SurRoL/{task}-v0")
        arms = getattr(env.unwrapped, "psms", None) or (env.unwrapped.psm,)
        built = [np.rad2deg(np.arctan2(a.world_T_rcm[1, 0], a.world_T_rcm[0, 0])) for a in arms]
        env.close()
        assert np.allclose(built, yaws), (task, built)
    client = physics.make_client()
    psm = Psm(client, PSM1_RCM, REFERENCE_PSM1_BASE_YAW_RAD, visual=False)
    target = kin.pose_from(np.array([0.55, 0.01, 0.70]), tool_down(0.3))
    sol = psm.ik(target)
    assert sol.within_limits
    psm.reset_joints(sol.q, 0.0)
    assert np.allclose(psm.tip_pose(), target, atol=1e-9)
    assert abs(np.rad2deg(sol.q[3])) > 60.0      # the yawed base turns the tool roll (the dVRK's joint values)
    client.disconnect()


# ---------------------------------------------------------------------- campaigns (the benchmark's, shorter)
def test_a_block_turned_on_its_peg_is_not_flung_off_the_board():
    """Bang-bang input (the benchmark's seeds 2 and 19) swipes a block round on its peg; the tool leaves it jammed
    there. Under PyBullet's default cone friction its contacts with the peg and the board then pushed each other in
    (40 N on a 0.1 N block), it sank 2.8 mm into the peg and was flung off the board (physics.ENABLE_CONE_FRICTION)."""
    r = physics_realism.run_policy("PegTransfer", "bang-bang", episodes=2, seeds=(2, 19))
    assert r.out_of_workspace == 0 and r.below_support == 0 and r.left_inside == 0
    assert r.overlap["object-static"] <= 1e-3, r.overlap


def test_a_glyph_block_released_over_its_groove_lands_without_sinking_in():
    """MatchBoard's oracle drops the block ~4 mm into its groove; with the objects' usual travel limit per physics step
    the flat block of pixel boxes tipped on landing and sank an edge 0.91–1.03 mm into the board (seeds 6 and 24):
    MatchBoard refines to physics.FLAT_BLOCK_TRAVEL_PER_STEP_M."""
    r = physics_realism.run_policy("MatchBoard", "oracle", episodes=2, seeds=(6, 24))
    assert r.successes == 2
    assert r.overlap["object-static"] <= 0.7e-3, r.overlap


def test_a_jack_pushed_along_the_table_stays_where_the_tool_can_reach_it():
    """Bang-bang input (seed 2) pushes a jack along the table with the blades' side while the tip runs along the edge of
    its clip box; the jack, leading the blades by its own reach, ended 8.4 mm beyond the box, where no tip can go. A
    rim on the table at the box's edges (objects.make_rim) stops it."""
    r = physics_realism.run_policy("PickAndPlace", "bang-bang", episodes=1, seeds=(2,))
    assert r.pushed_out == 0, f"a jack ended {1000 * r.pushed_out_by:.1f} mm beyond the tip's clip box"
    assert r.overlap["object-static"] <= 1e-3 and r.overlap["tool-static"] <= 1e-3, r.overlap


def test_a_needle_rocking_on_its_arc_after_landing_is_not_kicked_into_the_table():
    """Random actions (seed 1) make PSM1 drop the needle from the air; it lands on its arc and rocks. Nearly at rest
    (its far end moving ~0.3 mm a physics step) it was left to the coarse step, where its own contacts kicked it 1.05
    mm into the table; the needle scenes refine to physics.NEEDLE_TRAVEL_PER_STEP_M."""
    r = physics_realism.run_policy("NeedleRegrasp", "random", episodes=1, seeds=(1,))
    assert r.overlap["object-static"] <= 1e-3, r.overlap


@pytest.mark.slow
@pytest.mark.parametrize("policy, task", [(policy, task) for policy in ("random", "bang-bang")
                                          for task in physics_realism.TASKS])
def test_rough_input_overlaps_nothing_by_more_than_1_mm_and_leaves_nothing_inside(policy, task):
    # (With PyBullet's default contact solver a block wedged on a peg crept 3.2 mm into it under random BiPegTransfer
    # actions, with no tool touching it; see physics.SOLVER_ITERATIONS.)
    r = physics_realism.run_policy(task, policy, episodes=10)
    assert r.left_inside == 0 and r.below_support == 0 and r.out_of_workspace == 0 and r.pushed_out == 0
    assert max(r.overlap.values()) <= 1e-3, r.overlap


@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.GRASPING_TASKS)
@pytest.mark.parametrize("kind", ["poke", "swipe"])
def test_pokes_and_swipes_with_a_closed_jaw_never_grasp(task, kind):
    r = physics_realism.run_poke_swipe(task, kind, episodes=10)
    assert r.grasps == 0


@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.DROP_TASKS)
def test_drops_from_0_to_60_mm_land_on_their_support(task):
    r = physics_realism.run_drops(task, episodes=14)
    assert r.below_support == 0 and r.left_inside == 0


@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.DROP_TASKS)
def test_drops_sink_at_most_1_mm_into_their_support(task):
    assert physics_realism.run_drops(task, episodes=14).overlap["object-static"] <= 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.TASKS)
def test_unit_box_actions_are_tracked_within_10_percent(task):
    assert physics_realism.run_tracking(task, episodes=30).tracking_error <= 0.10


@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.TASKS)
@pytest.mark.parametrize("policy", physics_realism.POLICIES)
def test_a_held_object_slips_at_most_2_mm_or_is_dropped(task, policy):
    r = physics_realism.run_policy(task, policy, episodes=5)
    assert r.max_slip <= physics.GRASP_MAX_SLIP_M
    assert r.grasps_not_between == 0


# Hand-overs included (BiPegTransfer's blades sank 1.4 mm into the block before the grasp held each blade where it
# stopped and one constraint drove a handed-over object; see grasp.py).
@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.TASKS)
def test_oracle_episodes_overlap_nothing_by_more_than_1_mm(task):
    r = physics_realism.run_policy(task, "oracle", episodes=5)
    assert max(r.overlap.values()) <= 1e-3, r.overlap


@pytest.mark.slow
@pytest.mark.parametrize("task", physics_realism.GRASPING_TASKS)
@pytest.mark.parametrize("kind", ["poke", "swipe"])
def test_pokes_and_swipes_press_nothing_in_by_more_than_1_mm(task, kind):
    r = physics_realism.run_poke_swipe(task, kind, episodes=10)
    assert r.overlap["object-static"] <= 1e-3 and r.left_inside == 0

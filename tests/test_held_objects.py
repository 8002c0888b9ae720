"""Held objects as solid as free ones: no blade inside, slip seen at every physics step, a grasp only with the object
between the blades' faces, and a realism probe that changes nothing. Each case replays a seed that failed before
(the figure it read is in the test's docstring); ``benchmarks/physics_realism.py`` runs them all (its held rows)."""

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import physics
from surrol_data.envs.psm import JAW_JOINTS
from surrol_data.envs.units import SCALING

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import physics_realism  # noqa: E402
from oracle_episode import oracle_until  # noqa: E402

_LIMIT_M = 1e-3


def test_bang_bang_while_holding_keeps_the_blades_out_of_the_held_block():
    """BiPegTransfer seed 4: whipped round by bang-bang wrist moves, the weak jaw motor let a blade of the hand holding
    the block close 1.49 mm into it (the jaw from 21° to 11°; the blades do not collide with what they hold)."""
    r = physics_realism.run_held("BiPegTransfer", "held-bang-bang", 1, seeds=[4])
    assert r.grasps >= 1
    assert r.held_blade <= _LIMIT_M, f"a blade {1000 * r.held_blade:.2f} mm inside the held block"


def test_a_held_block_pushed_down_keeps_the_blades_out_and_slips_at_most_2_mm_or_drops():
    """MatchBoard seed 2, the tool pushed down 40 steps with the block in hand: the weld crept (a fifth of its error
    corrected per physics step), the block slipped 3.34 mm within a step uncounted, and a blade stood 2.29 mm
    inside it."""
    r = physics_realism.run_held("MatchBoard", "held-press", 1, seeds=[2])
    assert r.grasps >= 1
    assert r.held_blade <= _LIMIT_M, f"a blade {1000 * r.held_blade:.2f} mm inside the held block"
    assert r.max_slip <= physics.GRASP_MAX_SLIP_M, f"held while slipped {1000 * r.max_slip:.2f} mm"


def test_a_held_gauze_pushed_down_stays_out_of_the_tray_floor():
    """GauzeRetrieve seed 1, the tool pushed down 40 steps with the gauze in hand: resting pressed on the floor it rose
    off it by a hair, Bullet's box-box test then found no contact, and the stalled arm drove the gauze 1.25 mm into the
    floor within that physics step (then dropped it as pressed in)."""
    r = physics_realism.run_held("GauzeRetrieve", "held-press", 1, seeds=[1])
    assert r.grasps >= 1
    assert r.overlap["object-static"] <= _LIMIT_M, f"the gauze {1000 * r.overlap['object-static']:.2f} mm in the tray"
    assert r.drops == 0


def test_a_held_block_pushed_down_stays_out_of_the_table():
    """MatchBoard seeds 1 and 2, the tool pushed down with the block in hand: as the gauze, the pressed block met no
    table for one physics step and went 1.32 mm into it (seed 1), or, dropped as pressed in and pushed on by the tool,
    1.60 mm (seed 2)."""
    r = physics_realism.run_held("MatchBoard", "held-press", 2, seeds=[1, 2])
    assert r.grasps >= 2
    assert r.overlap["object-static"] <= _LIMIT_M, f"the block {1000 * r.overlap['object-static']:.2f} mm in the table"


def test_a_carried_gauze_stays_between_the_blades_under_bang_bang_input():
    """GauzeRetrieve seed 0, bang-bang input while the gauze is carried: put in the hand after each physics step by a
    blade's stored frame, which is the one the step began with, the gauze lagged the blades by a step's motion and a
    blade read 1.38 mm inside it (the probe's slip, read the same way, 1.73 mm; 0.10 in truth)."""
    r = physics_realism.run_held("GauzeRetrieve", "held-bang-bang", 1, seeds=[0])
    assert r.grasps >= 1
    assert r.held_blade <= _LIMIT_M, f"a blade {1000 * r.held_blade:.2f} mm inside the carried gauze"
    assert r.max_slip <= 0.5e-3, f"the carried gauze read {1000 * r.max_slip:.2f} mm off its grip"


def test_a_ring_let_go_under_the_spinning_wrist_is_not_pushed_into_its_board():
    """PegBoard seed 2, the wrist spun while holding the ring: pressed on the board, the ring was let go, and the
    closed jaw spinning against it pushed it, a free body of boxes on the board's box, 2.6 mm into the board (a blade
    1.74 mm into the ring)."""
    r = physics_realism.run_held("PegBoard", "held-spin", 1, seeds=[2])
    assert r.grasps >= 1
    assert r.overlap["object-static"] <= _LIMIT_M, f"the ring {1000 * r.overlap['object-static']:.2f} mm in the board"
    assert r.overlap["tool-object"] <= _LIMIT_M, f"a blade {1000 * r.overlap['tool-object']:.2f} mm in the ring"


def test_a_needle_whipped_round_in_the_hand_is_not_dropped_for_a_slip_it_did_not_make():
    """NeedlePick seed 2, bang-bang input while holding the needle: the drop rule read the needle after a physics step
    against the blade's frame from before it, i.e. a step's motion off its grip (1.95 mm more than its 0.12 mm slip),
    dropped it, and the needle, flung tumbling, landed 1.44 mm into the pad."""
    r = physics_realism.run_held("NeedlePick", "held-bang-bang", 1, seeds=[2])
    assert r.grasps >= 1
    assert r.drops == 0, "dropped for a slip it did not make"
    assert r.overlap["object-static"] <= _LIMIT_M, f"the needle {1000 * r.overlap['object-static']:.2f} mm in the pad"


def _needle_welded(seed: int = 6):
    """NeedlePick under its oracle until the needle is welded in the hand: (env, its unwrapped env, the last info)."""
    env, u, _, info = oracle_until("NeedlePick", seed, lambda u: u.grasp.welded)
    return env, u, info


def test_a_held_needle_slipped_into_a_blade_is_dropped():
    """The blades do not collide with what they hold, so an object slipping across the gap meets nothing: a needle slid
    0.8 mm into a blade, well within the 2 mm slip limit, was held on with the blade inside it (NeedlePick seed 6, the
    needle moved in the hand between two physics steps; a needle gripped again after a drop and pressed on the pad slid
    1.87 mm in the hand with a blade 1.24 mm inside it). A blade 0.6 mm inside the held object is a lost hold, dropped
    and counted."""
    env, u, info = _needle_welded()
    for _ in range(2):   # still, so that nothing moves within a physics step
        env.step(np.array([0.0, 0.0, 0.0, 0.0, -1.0], np.float32))
    g, c = u.grasp, u.client
    assert g.welded and g.slip_m() < 0.3e-3
    blade = c.getLinkState(u.psm.body, JAW_JOINTS[0])
    away = np.asarray(c.getMatrixFromQuaternion(blade[5])).reshape(3, 3)[:, 0]   # blade 6's +x: into blade 6
    pos, quat = c.getBasePositionAndOrientation(u.object_id)
    c.resetBasePositionAndOrientation(u.object_id, (np.asarray(pos) + 0.8e-3 * SCALING * away).tolist(), quat)
    c.performCollisionDetection()
    movable = {u.object_id, u.psm.body}
    depth = -min(p[8] for p in c.getClosestPoints(u.psm.body, u.object_id, 0.0, JAW_JOINTS[0])) / SCALING
    assert 0.6e-3 < depth < 1e-3 and g.slip_m() < physics.GRASP_MAX_SLIP_M, (depth, g.slip_m())
    assert g.gives(movable, 0.0) and g.drops == 1 and not g.attached
    env.close()


def test_a_jaw_chattering_above_a_jack_never_tip_pinches_it():
    """PickAndPlace seed 0, the jaw closed 3 mm above the oracle's grasp point on a jack's arm, then lifted: the blade
    ends touched two faces of the arm ~90° apart, each within 45° of its inner face, and the jack was gripped and
    lifted at 8 of 8 closures."""
    r = physics_realism.run_chatter("PickAndPlace", 1, seeds=[0])
    assert r.grasps == 0 and r.tip_pinch_lifts == 0, (r.grasps, r.tip_pinch_lifts)
    assert r.pinches >= 6, r.pinches   # (the closures were tip-pinches: 7 of 8 touched it, normals 83–103° apart)


def test_each_chatter_closure_is_a_tip_pinch_on_the_jack_where_it_now_lies():
    """PickAndPlace seed 4, the jaw closed again and again at the point first aimed at: the tip-pinches (normals
    87–97° apart, none gripped) nudged the jack until an arm lay across the blade ends, touched on opposite sides at
    its widest (normals 135–163° apart, 7–19° above the horizontal, on both inner faces 9.4–10.0 mm along the blades,
    6.5–6.7 mm out on the arm), and the jaw gripped and lifted it at 4 of 8 closures: a grasp, rightly made, that the
    case counted as a tip-pinch lift. Aimed afresh at the jack each time, every closure is a tip-pinch, and none grips."""
    r = physics_realism.run_chatter("PickAndPlace", 1, seeds=[4])
    assert r.grasps == 0 and r.tip_pinch_lifts == 0, (r.grasps, r.tip_pinch_lifts)
    assert r.pinches == 8, r.pinches


def test_a_held_object_that_slips_past_2_mm_within_a_step_is_dropped_and_counted():
    """Checked once per control step, a needle yanked out of the hand for a physics step and pushed back was never
    counted (2.81 mm out after the yank, 0.37 mm at the step's end, still held): the drop happens at the physics step
    the slip passes 2 mm."""
    env, u, info = _needle_welded()
    assert u.grasp.welded and info["drops"] == 0
    c = u.client
    seen = {"substep": 0, "slip": 0.0}

    def yank_then_let_go(e):   # a physics step's pull a quarter past the weld's force, then one pushing back
        seen["substep"] += 1
        if e.grasp.attached:
            seen["slip"] = max(seen["slip"], e.grasp.slip_m())
        if seen["substep"] <= 2 and e.grasp.attached:
            pos = c.getBasePositionAndOrientation(e.object_id)[0]
            up = 1.0 if seen["substep"] == 1 else -1.0
            c.applyExternalForce(e.object_id, -1, [0.0, 0.0, up * 1.25 * physics.GRASP_MAX_FORCE], pos, c.WORLD_FRAME)

    u.substep_hook = yank_then_let_go
    obs, _, _, _, info = env.step(np.array([0.0, 0.0, 0.0, 0.0, -1.0], np.float32))
    u.substep_hook = None
    env.close()
    assert seen["slip"] <= physics.GRASP_MAX_SLIP_M + 1e-9 or info["drops"] == 1, seen
    assert info["drops"] == 1


@pytest.mark.slow
@pytest.mark.parametrize("task, kind", [(t, k) for t in physics_realism.HELD_TASKS for k in physics_realism.HELD_RUNS])
def test_held_rows_stay_within_1_mm_on_every_task(task, kind):
    """The benchmark's held rows on their first 5 seeds (pushed down, whipped round, spun, with the object in hand, on
    every PSM task that holds one): no blade or support more than 1 mm inside the held object, every grasp with the
    object between the blades, slip past 2 mm only as a counted drop (10 seeds each: docs/physics.md)."""
    r = physics_realism.run_held(task, kind, 5)
    assert r.grasps >= 1 and r.grasps_not_between == 0
    assert r.held_blade <= _LIMIT_M and r.held_static <= _LIMIT_M, (r.held_blade, r.held_static)
    assert max(r.overlap.values()) <= _LIMIT_M, r.overlap
    assert r.max_slip <= physics.GRASP_MAX_SLIP_M


def _episode(task: str, seed: int, policy: str, probed: bool, steps: int = 40) -> list:
    env = gym.make(f"SurRoL/{task}-v0")
    u = env.unwrapped
    obs, _ = env.reset(seed=seed)
    probe = physics_realism.Probe()
    if probed:
        probe.attach(u)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        action = u.oracle_action(obs) if policy == "oracle" else rng.uniform(-1, 1, env.action_space.shape)
        obs, *_ = env.step(action)
        out.append(obs["observation"].tobytes())
        if probed:   # the per-step reads the benchmark makes between steps
            for g in physics_realism.grasps_of(u):
                physics_realism.between_blades(u.client, g.psm.body, g.object_id)
    env.close()
    return out


def test_the_realism_probe_leaves_the_episode_bit_identical():
    """The probe read the wrist's frame with a forward-kinematics pass at every physics step, which moved the solver's
    next result by ~6e-8, growing to millimetres (a NeedleRings tip 91 mm apart); a carried gauze followed its hand
    at every step by such a pass too."""
    for task, seed, policy in (("NeedleRings", 0, "random"), ("GauzeRetrieve", 0, "oracle")):
        assert _episode(task, seed, policy, True) == _episode(task, seed, policy, False), (task, policy)

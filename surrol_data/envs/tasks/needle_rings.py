"""NeedleRings: pass the needle through a ring, handing it off from PSM1 to PSM2 (bimanual, pitch mode).

The paper: "the trainee needs to hand off the needle using two robot arms to pass it through the ring". As in
suturing, a curved needle goes through by turning about its own arc centre, so its tip follows the arc. The
needle hangs upright in a vertical plane normal to world x (as in NeedleRegrasp), held by PSM1 at its +y side;
both tools work in pitch mode, whose tilt turns a held needle within that plane. A ring stands on a post on
the needle's circle, 30° of turn ahead of its leading tip (the −y end), its axis along the arc. PSM1 turns the
needle 70° so that the tip goes through the ring and comes out beyond it; PSM2 grips the emerged part, PSM1
lets go, and PSM2 turns the needle on to 100°, drawing it through.

Ring (real millimetres): 7.5 mm mean diameter (inner 6, outer 9), 1.5 mm thick, on a 1.5 mm post — the
eyelets of the suture-training "needle rings" boards (SurRoL-v2's ``ring_cyl`` ×0.03 is about this size;
its needle is the 40 mm one scaled 2.1×; here the project's 40 mm needle, 1.24 mm wire, is kept, so the
ring sits with 2.4 mm of play around the wire).

Achieved goal (4): the needle tip (leading end) position and whether the needle passes through the ring's
hole (1) or not (0). Desired goal: where the tip is once the needle has turned 100° about its start centre,
and 1. Success: tip within 5 mm and threaded.
"""

from __future__ import annotations

import numpy as np

from surrol_data.envs import objects, physics, ring_board
from surrol_data.envs.numeric import norm
from surrol_data.envs.bimanual_env import ArmStart, approach_direction
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import matrix_to_quat
from surrol_data.envs.tasks.needle_regrasp import _UPRIGHT, CLOSE, OPEN, NeedleRegrasp, _rot_x
from surrol_data.envs.units import SCALING, SUCCESS_TOLERANCE_M

R = objects.NEEDLE_RADIUS
RING_MEAN_RADIUS = 3.75e-3
RING_WIDTH = 1.5e-3
RING_THICKNESS = 1.5e-3
RING_INNER_RADIUS = RING_MEAN_RADIUS - RING_WIDTH / 2
RING_COLOUR = (0.6, 0.6, 0.62, 1.0)
POST_HALF_WIDTH = 0.75e-3


def needle_point(beta: float) -> np.ndarray:
    """Needle-frame point ``beta`` rad of arc behind the leading tip (0: the tip at (0, −R); π/2: the midpoint)."""
    return np.array([-R * np.sin(beta), -R * np.cos(beta), 0.0])


TIP = needle_point(0.0)
ARC = np.stack([needle_point(b) for b in np.linspace(0.0, np.pi, 37)])


class NeedleRings(NeedleRegrasp):
    TASK = "Pass the needle through the ring: turn it in with the right arm, hand it off, draw it through with the left."
    ROTATION_MODE = ("pitch", "pitch")
    GOAL_DIM = 4
    # Both arms may reach past the centre line: the needle turns about a centre between them.
    WORKSPACES = (np.array([[0.54, 0.60], [-0.02, 0.08], [0.69, 0.745]]),
                  np.array([[0.54, 0.60], [-0.08, 0.02], [0.69, 0.745]]))
    HELD_AT_START = 0
    ORACLE_GAIN = 0.5
    CENTRE_RANGE = np.array([[0.555, 0.585], [-0.004, 0.004]])   # nominal needle centre (x, y); z below
    CENTRE_Z = 0.712
    START_OFFSET_M = 0.003          # the needle starts this far (per axis, uniform) from its nominal centre
    START_ROLL_RANGE = (np.deg2rad(-15.0), 0.0)
    RING_AT = np.deg2rad(30.0)      # the ring's place on the circle, in turn of the needle from its nominal start
    HANDOFF_AT = np.deg2rad(70.0)   # PSM1 turns the needle this far, then PSM2 takes it
    GOAL_AT = np.deg2rad(100.0)     # ... and turns it on to here
    TURN_STEP = np.deg2rad(10.0)    # the oracle turns the needle in steps this large
    HOLD_PITCH = (np.deg2rad(-30.0), np.deg2rad(-20.0))   # PSM1 at the start; PSM2 when it takes the needle
    TAKE_BEHIND_TIP = np.deg2rad(15.0)                     # PSM2 grips this far (arc) behind the tip
    HOLD_POINT = np.deg2rad(150.0)                         # PSM1 holds the needle here (key point 5)
    SIDE_STEP_M = 0.011             # PSM2 comes in from this far off the needle's plane (clear of ring and wire)

    # ------------------------------------------------------------------ scene
    def build_scene(self) -> None:
        super().build_scene()
        self.ring_body = -1

    def _place_ring(self, centre: np.ndarray) -> None:
        """The ring on its post at ``RING_AT`` along the nominal circle, axis along the arc (a static body)."""
        if self.ring_body >= 0:
            self.client.removeBody(self.ring_body)
        turn = _rot_x(self.RING_AT)
        self.ring_centre = centre + turn @ _UPRIGHT @ TIP
        self.ring_axis = turn @ np.array([0.0, 0.0, -1.0])   # the arc's tangent: the way the tip moves
        # Ring frame: z along the axis, x along world x.
        z = self.ring_axis
        x = np.array([1.0, 0.0, 0.0])
        ring_rot = np.stack([x, np.cross(z, x), z], axis=1)
        halves, centres, quats = ring_board.ring_boxes(RING_MEAN_RADIUS, RING_WIDTH, RING_THICKNESS)
        # Post: from the ring's lowest outer point straight down to the table.
        low_dir = ring_rot[:, 1] if ring_rot[2, 1] < 0 else -ring_rot[:, 1]
        low = self.ring_centre + (RING_MEAN_RADIUS + RING_WIDTH / 2 - 0.3e-3) * low_dir
        post_height = low[2] - objects.TABLE_TOP_Z
        post_centre = np.array([low[0], low[1], objects.TABLE_TOP_Z + post_height / 2])
        ring_quat = matrix_to_quat(ring_rot)
        frames, orients = [], []
        for c, q in zip(centres, quats):
            p, o = pb.multiplyTransforms([0, 0, 0], ring_quat, c, q)
            frames.append((np.asarray(p) + self.ring_centre * SCALING).tolist())
            orients.append(list(o))
        halves.append((np.array([POST_HALF_WIDTH, POST_HALF_WIDTH, post_height / 2]) * SCALING).tolist())
        frames.append((post_centre * SCALING).tolist())
        orients.append([0, 0, 0, 1])
        n = len(halves)
        col = self.client.createCollisionShapeArray([pb.GEOM_BOX] * n, halfExtents=halves,
                                                    collisionFramePositions=frames, collisionFrameOrientations=orients)
        vis = self.client.createVisualShapeArray([pb.GEOM_BOX] * n, halfExtents=halves, visualFramePositions=frames,
                                                 visualFrameOrientations=orients,
                                                 rgbaColors=[RING_COLOUR] * n) if self.visual else -1
        self.ring_body = self.client.createMultiBody(0.0, col, vis, [0, 0, 0], useMaximalCoordinates=True)

    # ------------------------------------------------------------------ episode
    def reset_task(self, rng):
        # The world is rebuilt every reset (BimanualEnv): the ring body went with the old one.
        self.ring_body = -1
        xy = rng.uniform(self.CENTRE_RANGE[:, 0], self.CENTRE_RANGE[:, 1])
        self.nominal_centre = np.array([xy[0], xy[1], self.CENTRE_Z])
        self._place_ring(self.nominal_centre)
        centre = self.nominal_centre + rng.uniform(-self.START_OFFSET_M, self.START_OFFSET_M, size=3)
        roll = rng.uniform(*self.START_ROLL_RANGE)
        rotation = _rot_x(roll) @ _UPRIGHT
        objects.set_needle_frame(self.client, self.object_id, centre, rotation)
        pitch1 = self.HOLD_PITCH[0] + roll
        tip1 = self._grasp_tip(centre + rotation @ needle_point(self.HOLD_POINT), pitch1)
        return (ArmStart(tip1, pitch1, self._contact_jaw_angle()),
                ArmStart(self._psm2_waiting_place(), self.HOLD_PITCH[1], physics.JAW_OPEN_RAD))

    def _psm2_waiting_place(self) -> np.ndarray:
        """Where PSM2 starts and waits while PSM1 turns the needle: above and behind the hand-off, off the
        needle's plane on the side it comes in from (see ``plan_oracle``). Its open blades span ~7 mm across
        that plane; from a place on the plane, the way down to the hand-off swept them across the turning
        needle's arc, and a touch there (0.5–1.8 N) knocked the needle out of PSM1's hand."""
        return np.array([self.nominal_centre[0] - self.SIDE_STEP_M, -0.04, 0.735])

    def sample_goal(self, rng):
        tip = self.nominal_centre + _rot_x(self.GOAL_AT) @ _UPRIGHT @ TIP
        return np.array([*tip, 1.0])

    # ------------------------------------------------------------------ state
    def needle_turn(self) -> float:
        """How far (rad) the needle has turned in its plane from upright (the leading tip moving down first)."""
        pos, rot = objects.needle_pose(self.client, self.object_id)
        d = rot @ TIP
        return float(np.arctan2(-d[2], -d[1]))

    def threaded(self) -> bool:
        """Whether the needle's arc crosses the ring's plane inside its hole."""
        pos, rot = objects.needle_pose(self.client, self.object_id)
        rel = pos + ARC @ rot.T - self.ring_centre
        axial = rel @ self.ring_axis
        radial = np.linalg.norm(rel - axial[:, None] * self.ring_axis, axis=1)
        for i in np.flatnonzero(np.signbit(axial[:-1]) != np.signbit(axial[1:])):
            w = axial[i] / (axial[i] - axial[i + 1])
            if (1 - w) * radial[i] + w * radial[i + 1] < RING_INNER_RADIUS:
                return True
        return False

    def object_state(self):
        pos, rot = objects.needle_pose(self.client, self.object_id)
        _, quat = self.client.getBasePositionAndOrientation(self.object_id)
        euler = np.asarray(self.client.getEulerFromQuaternion(quat))
        return (pos, (pos + rot @ TIP, euler), (pos + rot @ needle_point(self.TAKE_BEHIND_TIP), euler))

    def achieved_goal(self) -> np.ndarray:
        pos, rot = objects.needle_pose(self.client, self.object_id)
        return np.array([*(pos + rot @ TIP), float(self.threaded())])

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        a, d = np.asarray(achieved_goal, np.float64), np.asarray(desired_goal, np.float64)
        close = norm(a[..., :3] - d[..., :3]) < SUCCESS_TOLERANCE_M
        return close & (np.abs(a[..., 3] - d[..., 3]) < 0.5)

    # ------------------------------------------------------------------ oracle
    def plan_oracle(self):
        c = self.nominal_centre
        start_turn = self.needle_turn()
        p1_start = self._rotation_angle(0, self.tip_pose(0))
        p2 = self.HOLD_PITCH[1]

        def turned(arm: int, turn: float):
            """Tip target of ``arm`` that turns the held needle to ``turn`` about the nominal centre."""
            def target(obs):
                o = np.asarray(obs["observation"], np.float64)
                tip, centre = o[7 * arm: 7 * arm + 3], o[14:17]
                d = o[23:26] - centre
                now = np.arctan2(-d[2], -d[1])
                return c + _rot_x(turn - now) @ (tip - centre)
            return target

        def take(obs):   # PSM2 on the needle's emerged part (observation key point 2)
            return np.asarray(obs["observation"][29:32], np.float64) + self.GRASP_INSET_M * approach_direction(p2)

        def back_off(arm: int, pitch: float):
            def target(obs):
                tip = np.asarray(obs["observation"][7 * arm: 7 * arm + 3], np.float64)
                return tip - 0.01 * approach_direction(pitch)
            return target

        wait2 = {"target": self._psm2_waiting_place(), "angle": p2, "jaw": OPEN, "tol": 1.0, "angle_tol": 10.0}
        steps = []
        # PSM1 brings the needle to its nominal pose, then turns it through the ring in TURN_STEP steps.
        turns = [0.0, *np.arange(self.TURN_STEP, self.HANDOFF_AT + 1e-9, self.TURN_STEP)]
        for k, turn in enumerate(turns):
            pitch = p1_start + (turn - start_turn)
            steps.append({"arms": ({"target": turned(0, turn), "angle": pitch, "jaw": CLOSE, "tol": 5e-4,
                                    "angle_tol": 0.03}, wait2)})
        p1_end = p1_start + (self.HANDOFF_AT - start_turn)
        hold1 = {"target": turned(0, self.HANDOFF_AT), "angle": p1_end, "jaw": CLOSE, "tol": 1.0, "angle_tol": 10.0}
        a2 = approach_direction(p2)

        def lined_up(obs):
            return take(obs) - 0.008 * a2

        def beside(obs):
            # Off the needle's plane (towards PSM2's side of x) first: a straight path would cross the needle's
            # arc, and the open blades span the plane.
            return lined_up(obs) - np.array([self.SIDE_STEP_M, 0.0, 0.0])

        steps += [
            {"arms": (hold1, {"target": beside, "angle": p2, "jaw": OPEN, "tol": 1e-3, "gain": 1.0})},
            {"arms": (hold1, {"target": lined_up, "angle": p2, "jaw": OPEN, "tol": 1e-3})},
            {"arms": (hold1, {"target": take, "angle": p2, "jaw": OPEN, "tol": 3e-4})},
            {"arms": (hold1, {"target": take, "angle": p2, "jaw": CLOSE, "tol": 2e-3, "angle_tol": 10.0}), "hold": 2},
            {"arms": ({**hold1, "jaw": OPEN}, {"target": take, "angle": p2, "jaw": CLOSE, "tol": 2e-3,
                                                "angle_tol": 10.0}), "hold": 1},
        ]
        retreat1 = {"target": back_off(0, p1_end), "angle": p1_end, "jaw": OPEN, "tol": 1.0, "angle_tol": 10.0}
        for turn in np.arange(self.HANDOFF_AT + self.TURN_STEP, self.GOAL_AT + 1e-9, self.TURN_STEP):
            pitch = p2 + (turn - self.HANDOFF_AT)
            steps.append({"arms": (retreat1, {"target": turned(1, turn), "angle": pitch, "jaw": CLOSE, "tol": 5e-4,
                                              "angle_tol": 0.03})})
        return steps

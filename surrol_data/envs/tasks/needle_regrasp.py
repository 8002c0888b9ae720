"""NeedleRegrasp: PSM1 holds a needle upright; hand it over to PSM2, which brings it to the green target.

The needle hangs in a vertical plane normal to world x, arc up (an "∩"), so both pitch-mode tools, whose jaws
open along world x, straddle its wire: PSM1 holds it at key point 5 (its +y side), PSM2 takes it at key point
4 (the −y side). Achieved goal = key point 4; the goal is the centre of PSM2's workspace ± N(5 mm) per axis.

The reference finds PSM1's grasp by a physics rejection loop (~0.4 s); here the needle is placed directly
between PSM1's jaws, at the jaw angle where the blades touch its wire, and the grasp constraint is attached:
the same start, deterministic, in about 3 ms.
"""

from __future__ import annotations

import numpy as np

from surrol_data.envs import objects, physics
from surrol_data.envs import kinematics as kin
from surrol_data.envs.bimanual_env import ArmStart, BimanualEnv, approach_direction

OPEN, CLOSE = 0.8, -0.8   # the reference oracle's jaw magnitude for this task

# Needle frame when upright with no roll: needle x (towards the arc's opening) points down, y along world y,
# so the arc rises above its centre and key points 4/5 sit 10 mm above it, 17.3 mm to either side.
_UPRIGHT = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
KEY_POINT_1, KEY_POINT_2 = 4, 5


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


class NeedleRegrasp(BimanualEnv):
    TASK = "Hand the needle over from PSM1 to PSM2 and bring it to the green target."
    ROTATION_MODE = ("pitch", "pitch")
    WORKSPACES = (np.array([[0.55, 0.60], [0.01, 0.08], [0.695, 0.745]]),
                  np.array([[0.55, 0.60], [-0.08, -0.01], [0.695, 0.745]]))
    HELD_AT_START = 0
    OBJECT_TRAVEL_PER_STEP_M = physics.NEEDLE_TRAVEL_PER_STEP_M   # a landed needle rocks (physics.py)
    ORACLE_GAIN = 0.5
    GOAL_SIGMA_M = 0.005
    NEEDLE_ROLL_RANGE = np.deg2rad(15.0)    # the reference's needle pitch U(−105°, −75°) about its upright pose
    HOLD_PITCH = (np.deg2rad(-30.0), np.deg2rad(30.0))   # tools tilted towards the needle from their own side
    GRASP_INSET_M = 0.002                  # wire this far inside the blade ends
    PREGRASP_BACKOFF_M = 0.008             # PSM2 lines up this far back along its tool axis before closing in
    HANDOVER_CENTRE_YZ = (0.0, 0.712)      # needle centre during the hand-over: midway between the arms

    def build_scene(self) -> None:
        self._needle_spec = objects.needle_spec(self.client, visual=self.visual)
        self.respawn_objects()

    def respawn_objects(self) -> None:
        self.object_id = objects.respawn_needle(self.client, self._needle_spec, self.object_id)

    # ------------------------------------------------------------------ geometry
    def _grasp_tip(self, key_point: np.ndarray, pitch: float) -> np.ndarray:
        """Tip position that holds ``key_point`` GRASP_INSET_M inside the blade ends of a tool at ``pitch``."""
        return key_point + self.GRASP_INSET_M * approach_direction(pitch)

    @classmethod
    def _contact_jaw_angle(cls) -> float:
        # Blades touch the wire where their half-opening at the wire's distance from the pivot equals its radius.
        reach = kin.TIP_LENGTH - cls.GRASP_INSET_M
        return 2.0 * np.arcsin(objects.NEEDLE_WIRE_RADIUS / reach) + np.deg2rad(0.5)

    def needle_key_point(self, index: int) -> np.ndarray:
        pos, rot = objects.needle_pose(self.client, self.object_id)
        return pos + rot @ objects.NEEDLE_WAYPOINTS[index]

    # ------------------------------------------------------------------ task
    def reset_task(self, rng):
        ws1, ws2 = self.WORKSPACES
        # Needle centre in the middle third of PSM1's workspace, rolled in its plane (as the reference samples it).
        third = (ws1[:, 1] - ws1[:, 0]) / 3
        centre = rng.uniform(ws1[:, 0] + third, ws1[:, 1] - third)
        roll = rng.uniform(-self.NEEDLE_ROLL_RANGE, self.NEEDLE_ROLL_RANGE)
        rotation = _rot_x(roll) @ _UPRIGHT
        objects.set_needle_frame(self.client, self.object_id, centre, rotation)
        pitch1 = self.HOLD_PITCH[0] + roll   # the grasp turns with the needle: same hold in every episode
        tip1 = self._grasp_tip(centre + rotation @ objects.NEEDLE_WAYPOINTS[KEY_POINT_2], pitch1)
        self._handover_centre = np.array([centre[0], *self.HANDOVER_CENTRE_YZ])
        return (ArmStart(tip1, pitch1, self._contact_jaw_angle()),
                ArmStart(ws2.mean(axis=1), self.HOLD_PITCH[1], physics.JAW_OPEN_RAD))

    def sample_goal(self, rng):
        return self.WORKSPACES[1].mean(axis=1) + rng.normal(0.0, self.GOAL_SIGMA_M, size=3)

    def object_state(self):
        pos, rot = objects.needle_pose(self.client, self.object_id)
        _, quat = self.client.getBasePositionAndOrientation(self.object_id)
        euler = np.asarray(self.client.getEulerFromQuaternion(quat))
        return (pos, (pos + rot @ objects.NEEDLE_WAYPOINTS[KEY_POINT_1], euler),
                (pos + rot @ objects.NEEDLE_WAYPOINTS[KEY_POINT_2], euler))

    def achieved_goal(self) -> np.ndarray:
        return self.needle_key_point(KEY_POINT_1)

    def plan_oracle(self):
        p1, p2 = self.HOLD_PITCH
        a1, a2 = approach_direction(p1), approach_direction(p2)
        handover = self._handover_centre
        carry_tip1 = self._grasp_tip(handover + _UPRIGHT @ objects.NEEDLE_WAYPOINTS[KEY_POINT_2], p1)
        take_tip2 = self._grasp_tip(handover + _UPRIGHT @ objects.NEEDLE_WAYPOINTS[KEY_POINT_1], p2)
        lined_up2 = take_tip2 - self.PREGRASP_BACKOFF_M * a2
        retreat1 = carry_tip1 - 0.01 * a1

        def take(obs):  # closed loop on the needle's key point 4 (observation[23:26])
            return np.asarray(obs["observation"][23:26], np.float64) + self.GRASP_INSET_M * a2

        def deliver(obs):  # move PSM2's tip by what key point 4 still lacks
            o = obs["observation"]
            return np.asarray(o[7:10] + obs["desired_goal"] - obs["achieved_goal"], np.float64)

        hold1 = {"target": carry_tip1, "angle": p1, "jaw": CLOSE, "tol": 2e-3, "angle_tol": 10.0}
        return [
            # PSM1 carries the needle to the middle, upright; PSM2 lines up behind key point 4, open.
            {"arms": ({"target": carry_tip1, "angle": p1, "jaw": CLOSE, "tol": 1e-3},
                      {"target": lined_up2, "angle": p2, "jaw": OPEN, "tol": 1e-3})},
            {"arms": (hold1, {"target": take, "angle": p2, "jaw": OPEN, "tol": 3e-4})},
            {"arms": (hold1, {"target": take, "angle": p2, "jaw": CLOSE, "tol": 2e-3, "angle_tol": 10.0}),
             "hold": 2},
            {"arms": ({**hold1, "jaw": OPEN}, {"target": take, "angle": p2, "jaw": CLOSE, "tol": 2e-3,
                                                "angle_tol": 10.0}), "hold": 1},
            {"arms": ({"target": retreat1, "angle": p1, "jaw": OPEN, "tol": 2e-3, "angle_tol": 10.0},
                      {"target": deliver, "angle": p2, "jaw": CLOSE, "tol": 1e-3, "angle_tol": 10.0})},
        ]

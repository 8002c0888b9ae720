"""NeedlePick: grasp the needle at its mid-arc and lift it to a goal point in the air."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import physics
from surrol_data.envs.psm_env import WORKSPACE, wrap_angle
from surrol_data.envs.tasks.needle_base import NeedleTaskBase

OPEN, CLOSE = 0.5, -0.5


class NeedlePick(NeedleTaskBase):
    TASK = "Pick up the needle by its middle and lift it to the green target."
    GOAL_XY_SIGMA_M = 0.01
    GOAL_Z_M = 0.7152
    ORACLE_GAIN = 0.4
    GRASP_DEPTH_M = 0.0002   # tip this far below the wire centre line: blades straddle the wire, clear of the pad
    LIFT_M = 0.005           # the weld forms once the squeezing jaws have lifted the needle this much (reference)

    def grasp_lift_condition(self) -> bool:
        return self.achieved_goal()[2] > self.object_start_z + self.LIFT_M

    def reset_task(self, rng):
        self.place_needle(rng)
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2].mean()])
        return start, 0.0, physics.JAW_OPEN_RAD

    def sample_goal(self, rng):
        xy = WORKSPACE[:2].mean(axis=1) + rng.normal(0.0, self.GOAL_XY_SIGMA_M, size=2)
        return np.array([xy[0], xy[1], self.GOAL_Z_M])

    def plan_oracle(self):
        wp = self.needle_waypoint(1)
        # Jaws must close across the wire: the jaw-opening direction along the needle's x axis at mid-arc.
        # Either heading works (the jaw is symmetric); take the one closer to the current tool yaw.
        yaw = self.needle_yaw()
        current = float(self.robot_state()[5])
        if abs(wrap_angle(yaw + np.pi - current)) < abs(wrap_angle(yaw - current)):
            yaw = float(wrap_angle(yaw + np.pi))
        grasp = wp - np.array([0.0, 0.0, self.GRASP_DEPTH_M])
        above = grasp + np.array([0.0, 0.0, 0.005])
        return [
            {"target": above, "yaw": yaw, "jaw": OPEN, "tol": 1e-3},
            {"target": grasp, "yaw": yaw, "jaw": OPEN, "tol": 3e-4},
            {"target": grasp, "yaw": yaw, "jaw": CLOSE, "tol": 2e-3, "hold": 2},
            # Closed loop on the carried needle: move the tip by what the needle still lacks.
            {"target": lambda obs: obs["observation"][:3] + obs["desired_goal"] - obs["achieved_goal"],
             "yaw": yaw, "jaw": CLOSE, "tol": 1e-3, "yaw_tol": 10.0},
        ]

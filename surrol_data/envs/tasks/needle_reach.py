"""NeedleReach: bring the closed tool tip to 5 mm above the needle's mid-arc."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import physics
from surrol_data.envs.psm_env import WORKSPACE
from surrol_data.envs.tasks.needle_base import NeedleTaskBase
from surrol_data.envs.units import ACTION_POSITION_M


class NeedleReach(NeedleTaskBase):
    TASK = "Reach the needle: bring the closed tool tip 5 mm above the middle of the needle."
    OBJECT_OBS = False
    BLOCK_JAW = True
    FIXED_YAW = True
    ORACLE_GAIN = 0.3

    def reset_task(self, rng):
        self.place_needle(rng)
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2, 1]])
        return start, 0.0, physics.JAW_CLOSED_RAD

    def sample_goal(self, rng):
        return self.needle_waypoint(1) + np.array([0.0, 0.0, 0.005])

    def achieved_goal(self) -> np.ndarray:
        return self.tip_pose()[:3, 3]

    def oracle_action(self, obs: dict) -> np.ndarray:
        # Proportional move straight at the goal, at most ORACLE_GAIN cm per axis per step; still once within 2 mm.
        err = np.asarray(obs["desired_goal"], np.float64) - obs["achieved_goal"]
        if np.linalg.norm(err) < 0.002:
            return np.zeros(5, dtype=np.float32)
        delta = err / ACTION_POSITION_M
        delta = delta / max(1.0, np.abs(delta).max()) * self.ORACLE_GAIN
        return np.array([*delta, 0.0, -1.0], dtype=np.float32)

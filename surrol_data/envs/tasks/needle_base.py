"""Shared scene of the needle tasks: a padded tray with a 40 mm suture needle lying on it."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import kinematics as kin
from surrol_data.envs import objects
from surrol_data.envs.psm_env import WORKSPACE, PsmEnv


class NeedleTaskBase(PsmEnv):
    NEEDLE_JITTER_M = 0.01           # needle xy = workspace centre ± U(1 cm)
    NEEDLE_YAW_RANGE = np.pi / 2     # needle heading ± U(90°)

    def build_scene(self) -> None:
        objects.make_tray(self.client, with_pad=True, visual=self.visual)
        self._needle_spec = objects.needle_spec(self.client, visual=self.visual)
        self.respawn_objects()

    def respawn_objects(self) -> None:
        self.object_id = objects.respawn_needle(self.client, self._needle_spec, self.object_id)

    def place_needle(self, rng: np.random.Generator) -> None:
        xy = WORKSPACE[:2].mean(axis=1) + rng.uniform(-self.NEEDLE_JITTER_M, self.NEEDLE_JITTER_M, size=2)
        yaw = rng.uniform(-self.NEEDLE_YAW_RANGE, self.NEEDLE_YAW_RANGE)
        objects.set_needle_pose(self.client, self.object_id, [xy[0], xy[1], objects.needle_rest_height()], yaw)

    def needle_waypoint(self, index: int) -> np.ndarray:
        pos, rot = objects.needle_pose(self.client, self.object_id)
        return pos + rot @ objects.NEEDLE_WAYPOINTS[index]

    def needle_yaw(self) -> float:
        _, rot = objects.needle_pose(self.client, self.object_id)
        return float(np.arctan2(rot[1, 0], rot[0, 0]))

    def object_state(self):
        pos, rot = objects.needle_pose(self.client, self.object_id)
        wp = pos + rot @ objects.NEEDLE_WAYPOINTS[1]
        euler = kin.euler_xyz(rot)
        return pos, wp, euler

    def achieved_goal(self) -> np.ndarray:
        return self.needle_waypoint(1)

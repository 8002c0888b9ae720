"""GauzeRetrieve: pick the gauze up from the tray and carry it to a goal point in the air."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import kinematics as kin
from surrol_data.envs import objects, physics
from surrol_data.envs.psm_env import WORKSPACE, PsmEnv
from surrol_data.envs.units import SCALING

OPEN, CLOSE = 0.5, -0.5


class GauzeRetrieve(PsmEnv):
    TASK = "Retrieve the gauze: grasp it and lift it to the green target."
    FIXED_YAW = True                 # the reference zeroes the yaw action: jaws always open along world x
    KINEMATIC_CARRY = True           # the lifted gauze, far from the tray, is carried without its weld (grasp.py)
    ORACLE_GAIN = 0.6
    GAUZE_JITTER_M = 0.01            # gauze xy = workspace centre ± U(1 cm)
    GOAL_XY_SIGMA_M = 0.02           # goal xy = workspace centre + N(0, 2 cm) per axis (unclipped, as the reference)
    GOAL_BELOW_TOP_M = 0.03          # goal z = workspace top − 3 cm
    GRASP_BELOW_CENTRE_M = 0.0007    # tip this far below the gauze centre: blades cover most of its height
    APPROACH_HEIGHT_M = 0.005
    LIFT_M = 0.005
    WELD_LIFT_M = 0.0025             # the weld forms once the squeezing jaws have lifted the gauze this much (reference)

    def build_scene(self) -> None:
        objects.make_tray(self.client, with_pad=False, origin_m=objects.BARE_TRAY_ORIGIN, visual=self.visual)
        self._gauze_spec = objects.gauze_spec(self.client, visual=self.visual)
        self.respawn_objects()

    def respawn_objects(self) -> None:
        if self.object_id >= 0:
            self.client.removeBody(self.object_id)
        self.object_id = self.client.createMultiBody(**self._gauze_spec)
        objects.configure_gauze(self.client, self.object_id)

    def reset_task(self, rng):
        xy = WORKSPACE[:2].mean(axis=1) + rng.uniform(-self.GAUZE_JITTER_M, self.GAUZE_JITTER_M, size=2)
        position = np.array([xy[0], xy[1], objects.gauze_rest_height()])
        self.client.resetBasePositionAndOrientation(self.object_id, (position * SCALING).tolist(), [0, 0, 0, 1])
        self.client.resetBaseVelocity(self.object_id, [0, 0, 0], [0, 0, 0])
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2].mean()])
        return start, 0.0, physics.JAW_OPEN_RAD

    def sample_goal(self, rng):
        xy = WORKSPACE[:2].mean(axis=1) + rng.normal(0.0, self.GOAL_XY_SIGMA_M, size=2)
        return np.array([xy[0], xy[1], WORKSPACE[2, 1] - self.GOAL_BELOW_TOP_M])

    def grasp_lift_condition(self) -> bool:
        return self.achieved_goal()[2] > self.object_start_z + self.WELD_LIFT_M

    def gauze_pose(self) -> tuple[np.ndarray, np.ndarray]:
        pos, quat = self.client.getBasePositionAndOrientation(self.object_id)
        rot = np.asarray(self.client.getMatrixFromQuaternion(quat)).reshape(3, 3)
        return np.asarray(pos) / SCALING, rot

    def object_state(self):
        pos, rot = self.gauze_pose()
        euler = kin.euler_xyz(rot)
        # The gauze has no waypoint link (the reference's obj_link1 = -1): the "waypoint" is the base itself.
        return pos, pos, euler

    def achieved_goal(self) -> np.ndarray:
        # (The position alone: gauze_pose's rotation matrix is not needed here.)
        return np.asarray(self.client.getBasePositionAndOrientation(self.object_id)[0]) / SCALING

    def plan_oracle(self):
        gauze = self.gauze_pose()[0]
        grasp = gauze - np.array([0.0, 0.0, self.GRASP_BELOW_CENTRE_M])
        above = grasp + np.array([0.0, 0.0, self.APPROACH_HEIGHT_M])
        lifted = grasp + np.array([0.0, 0.0, self.LIFT_M])
        return [
            {"target": above, "yaw": 0.0, "jaw": OPEN, "tol": 1e-3},
            {"target": grasp, "yaw": 0.0, "jaw": OPEN, "tol": 3e-4},
            {"target": grasp, "yaw": 0.0, "jaw": CLOSE, "tol": 2e-3, "hold": 2},
            {"target": lifted, "yaw": 0.0, "jaw": CLOSE, "tol": 2e-3},
            # Closed loop on the carried gauze: move the tip by what the gauze still lacks.
            {"target": lambda obs: obs["observation"][:3] + obs["desired_goal"] - obs["achieved_goal"],
             "yaw": 0.0, "jaw": CLOSE, "tol": 1e-3},
        ]

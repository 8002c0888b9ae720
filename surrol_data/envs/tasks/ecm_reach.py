"""ECMReach: move the endoscope's EEF to a goal point (5 mm tolerance)."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import ecm_kinematics as ekin
from surrol_data.envs.ecm_env import EcmEnv, robot_state
from surrol_data.envs.physics import pb
from surrol_data.envs.units import ACTION_POSITION_M, SUCCESS_TOLERANCE_M

# Goal box (world, real metres) below and around the RCM at (0.531, 0, 0.784); the EEF starts at its top centre.
WORKSPACE = np.array([[0.45, 0.55], [-0.05, 0.05], [0.60, 0.70]])
GOAL_MARKER_HALF_M = 0.009     # the reference's goal sphere (r = 3 mm) drawn 3× larger
GOAL_COLOUR = (0.1, 0.9, 0.1, 1.0)


class ECMReach(EcmEnv):
    TASK = "Move the endoscope tip to the green target."
    ACTION_DIM = 3
    OBS_DIM = 6
    GOAL_DIM = 3
    ORACLE_GAIN = 0.2

    def build_scene(self) -> None:
        self.goal_marker = -1
        if self.visual:
            vis = self.client.createVisualShape(pb.GEOM_SPHERE, radius=GOAL_MARKER_HALF_M, rgbaColor=GOAL_COLOUR)
            self.goal_marker = self.client.createMultiBody(0.0, -1, vis, [0, 0, 0])

    def reset_task(self, rng):
        start = [WORKSPACE[0].mean(), WORKSPACE[1].mean(), WORKSPACE[2, 1]]
        return ekin.ecm_ik_position(self.ecm.world_to_rcm(start), 0.0)

    def sample_goal(self, rng):
        return rng.uniform(WORKSPACE[:, 0], WORKSPACE[:, 1])

    def after_reset(self) -> None:
        self._goal_rcm = np.array(self.ecm.world_to_rcm(self.goal))
        if self.goal_marker >= 0:
            self.client.resetBasePositionAndOrientation(self.goal_marker, self.goal.tolist(), [0, 0, 0, 1])

    def apply_action(self, action) -> None:
        # 1 = 1 cm of EEF motion along the RCM frame's axes, from where the EEF is now; roll is held.
        m = self.ecm.eef_rcm
        step = ACTION_POSITION_M
        target = (m[0][3] + action[0] * step, m[1][3] + action[1] * step, m[2][3] + action[2] * step)
        self.ecm.command_eef_position_rcm(target, self.ecm.q_target[3])

    def action_axes(self) -> np.ndarray:
        return self.ecm.world_T_rcm[:3, :3]     # 1 = 1 cm along the RCM frame's axes

    def observe(self):
        return robot_state(self.ecm.eef_rcm), self.ecm.eef_position_world()

    def is_success(self, achieved_goal, desired_goal):
        d = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
        return d < SUCCESS_TOLERANCE_M

    def action_error(self, obs: dict) -> np.ndarray:
        """(dx, dy, dz, droll) in action units that would bring the EEF onto the goal (what a person aims for)."""
        achieved_rcm = np.array(self.ecm.world_to_rcm(obs["achieved_goal"]))
        goal_rcm = np.array(self.ecm.world_to_rcm(obs["desired_goal"]))
        return np.array([*(goal_rcm - achieved_rcm) / ACTION_POSITION_M, 0.0])

    def oracle_action(self, obs: dict) -> np.ndarray:
        """Straight at the goal in the RCM frame, at most ``ORACLE_GAIN`` cm per axis per step (reference gain 0.2)."""
        achieved_rcm = np.array(self.ecm.world_to_rcm(obs["achieved_goal"]))
        goal_rcm = np.array(self.ecm.world_to_rcm(obs["desired_goal"]))
        delta = (goal_rcm - achieved_rcm) / ACTION_POSITION_M
        delta = delta / max(1.0, np.abs(delta).max()) * self.ORACLE_GAIN
        return delta.astype(np.float32)

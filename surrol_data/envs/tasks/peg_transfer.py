"""PegTransfer: lift the red block off its peg and thread it onto the target peg."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import kinematics as kin
from surrol_data.envs import peg_board, physics
from surrol_data.envs.psm_env import WORKSPACE, PsmEnv, wrap_angle
from surrol_data.envs.tasks.peg_blocks import PegBlocksScene

OPEN, CLOSE = 0.5, -0.5


class PegTransfer(PegBlocksScene, PsmEnv):
    TASK = "Transfer the red block from its peg onto the peg marked by the green target."
    ORACLE_GAIN = 0.7                # the reference's gain, used near the blocks and pegs
    TRANSIT_GAIN = 1.0               # full speed (1 cm per step) on the long moves above the pegs
    GRASP_DEPTH_M = 0.0025           # tip below the block's top face when grasping a wall
    PEG_CLEARANCE_M = 0.003          # tip above the peg tops on the approach; carried block bottom above them
    RELEASE_DEPTH_M = 0.003          # block bottom below the goal peg's top when the jaw opens (peg in the hole)

    # ------------------------------------------------------------------ scene
    def reset_task(self, rng):
        self.place_blocks(rng)
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2, 1]])
        return start, 0.0, physics.JAW_OPEN_RAD

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = super().reset(seed=seed, options=options)
        self.sleep_blocks()   # the base class put the red block to sleep; the others rest too
        return obs, info

    # ------------------------------------------------------------------ observation and success
    def object_state(self):
        pos, rot = peg_board.block_pose(self.client, self.object_id)
        waypoint = pos + rot @ peg_board.BLOCK_WAYPOINTS[1]
        euler = kin.euler_xyz(rot)
        return pos, waypoint, euler

    # ------------------------------------------------------------------ oracle
    def plan_oracle(self):
        tip = self.tip_pose()[:3, 3]
        current_yaw = float(self.robot_state()[5])
        tips, normal_yaws = peg_board.wall_grasps(self.client, self.object_id, self.GRASP_DEPTH_M)
        # The jaw is symmetric: a wall can be grasped at its normal's yaw or that plus π. Take the wall whose
        # grasp yaw is nearest the current one (the hexagon always has one within 30°), and of the two
        # opposite walls that share it, the one nearer the tip.
        yaws = np.array([y if abs(wrap_angle(y - current_yaw)) <= np.pi / 2 else wrap_angle(y + np.pi)
                         for y in normal_yaws], dtype=np.float64)
        turn = np.round(np.abs(wrap_angle(yaws - current_yaw)), 6)  # rounded: opposite walls tie exactly
        k = int(np.lexsort((np.linalg.norm(tips[:, :2] - tip[:2], axis=1), turn))[0])
        grasp, yaw = tips[k], float(yaws[k])
        above = np.array([grasp[0], grasp[1], self.board.peg_top_z + self.PEG_CLEARANCE_M])
        # Carried block: its bottom lies (block height − grasp depth) below the tip.
        tip_to_bottom = peg_board.BLOCK_HEIGHT - self.GRASP_DEPTH_M
        carry_z = self.board.peg_top_z + self.PEG_CLEARANCE_M + tip_to_bottom
        lifted = np.array([grasp[0], grasp[1], carry_z])
        release_centre_z = self.board.peg_top_z - self.RELEASE_DEPTH_M + peg_board.BLOCK_HEIGHT / 2

        def over_goal(obs):
            # Closed loop on the carried block: shift the tip by the block's xy error, at carrying height.
            t = obs["observation"][:3].astype(np.float64)
            err = obs["desired_goal"].astype(np.float64) - obs["achieved_goal"]
            return np.array([t[0] + err[0], t[1] + err[1], carry_z])

        def onto_peg(obs):
            t = obs["observation"][:3].astype(np.float64)
            err = obs["desired_goal"].astype(np.float64) - obs["achieved_goal"]
            return np.array([t[0] + err[0], t[1] + err[1], t[2] + release_centre_z - obs["achieved_goal"][2]])

        stay = lambda obs: obs["observation"][:3].astype(np.float64)  # noqa: E731
        retreat = lambda obs: np.array([*obs["observation"][:2], carry_z], dtype=np.float64)  # noqa: E731
        return [
            {"target": above, "yaw": yaw, "jaw": OPEN, "tol": 1e-3, "gain": self.TRANSIT_GAIN},
            {"target": grasp, "yaw": yaw, "jaw": OPEN, "tol": 3e-4},
            {"target": grasp, "yaw": yaw, "jaw": CLOSE, "tol": 2e-3, "hold": 2},
            {"target": lifted, "yaw": yaw, "jaw": CLOSE, "tol": 2e-3, "gain": self.TRANSIT_GAIN},
            {"target": over_goal, "yaw": yaw, "jaw": CLOSE, "tol": 1e-3, "gain": self.TRANSIT_GAIN},
            {"target": onto_peg, "yaw": yaw, "jaw": CLOSE, "tol": 1e-3},
            {"target": stay, "yaw": yaw, "jaw": OPEN, "tol": 1.0, "yaw_tol": 10.0, "hold": 1},
            {"target": retreat, "yaw": yaw, "jaw": OPEN, "tol": 2e-3},
        ]

"""BiPegTransfer: PSM2 lifts the red block off its peg, hands it over to PSM1, which threads it on the goal peg.

Six blocks start on the lower peg cluster (the −y half of the board, PSM2's side); the goal is one of the
six upper pegs (PSM1's side). Scene, block geometry and the success test (xy within 5 mm and |dz| within
4 mm of the goal peg's origin) are PegTransfer's; both arms work in yaw mode.
"""

from __future__ import annotations

import numpy as np

from surrol_data.envs import peg_board, physics
from surrol_data.envs.bimanual_env import ArmStart, BimanualEnv
from surrol_data.envs.psm_env import wrap_angle
from surrol_data.envs.tasks.peg_blocks import PegBlocksScene
from surrol_data.envs.tasks.peg_transfer import PegTransfer

OPEN, CLOSE = 0.5, -0.5


class BiPegTransfer(PegBlocksScene, BimanualEnv):
    TASK = ("Lift the red block with the left arm, hand it over to the right arm, and place it on the peg "
            "marked by the green target.")
    ROTATION_MODE = ("yaw", "yaw")
    # Each arm may reach 1 cm past the board's centre line: the hand-over holds the block there by its far wall
    # (the reference's ±4 mm clip margin alone would stop the receiving tool short of it).
    WORKSPACES = (np.array([[0.50, 0.60], [-0.01, 0.05], [0.686, 0.745]]),
                  np.array([[0.50, 0.60], [-0.05, 0.01], [0.686, 0.745]]))
    ORACLE_GAIN = 0.7
    TRANSIT_GAIN = 1.0                 # free-space moves: 1 cm per step, within the arms' speed limits
    NUM_BLOCKS = 6
    GRASP_DEPTH_M = PegTransfer.GRASP_DEPTH_M
    PEG_CLEARANCE_M = PegTransfer.PEG_CLEARANCE_M
    RELEASE_DEPTH_M = PegTransfer.RELEASE_DEPTH_M
    HOVER_M = 0.01                     # PSM1 waits this far above its grasp while PSM2 brings the block
    HANDOVER_Y = 0.0                   # the block is passed over the board's centre line

    def reset_task(self, rng):
        self.place_blocks(rng)
        ws1, ws2 = self.WORKSPACES
        return (ArmStart(np.array([ws1[0, 0], ws1[1, 1], ws1[2, 1]]), 0.0, physics.JAW_OPEN_RAD),
                ArmStart(np.array([ws2[0, 0], ws2[1, 0], ws2[2, 1]]), 0.0, physics.JAW_OPEN_RAD))

    def settle_objects(self) -> None:
        self.sleep_blocks()

    # ------------------------------------------------------------------ observation
    def object_state(self):
        pos, rot = peg_board.block_pose(self.client, self.object_id)
        _, quat = self.client.getBasePositionAndOrientation(self.object_id)
        euler = np.asarray(self.client.getEulerFromQuaternion(quat))
        return (pos, (pos + rot @ peg_board.BLOCK_WAYPOINTS[1], euler),
                (pos + rot @ peg_board.BLOCK_WAYPOINTS[2], euler))

    # ------------------------------------------------------------------ oracle
    def plan_oracle(self):
        block, _ = peg_board.block_pose(self.client, self.object_id)
        tips, normal_yaws = peg_board.wall_grasps(self.client, self.object_id, self.GRASP_DEPTH_M)
        # Both tools hold the block by opposite walls, with the jaws opening along the wall normals. The walls
        # facing ±x (within 30° for any block yaw) keep both tools near their start yaw and side by side over
        # the board's centre line; PSM2 takes the one of the pair nearer its tip.
        grasp_yaws = wrap_angle(normal_yaws + np.pi / 2) - np.pi / 2          # folded into [−90°, 90°)
        facing_x = np.argsort(np.abs(grasp_yaws))[:2]
        tip2 = self.tip_pose(1)[:3, 3]
        k2 = int(min(facing_x, key=lambda k: np.linalg.norm(tips[k, :2] - tip2[:2])))
        k1 = (k2 + 3) % 6
        yaw = float(grasp_yaws[k2])
        offset1 = tips[k1] - block                       # PSM1's grasp relative to the block centre
        grasp2 = tips[k2]

        tip_to_bottom = peg_board.BLOCK_HEIGHT - self.GRASP_DEPTH_M
        carry_z = self.board.peg_top_z + self.PEG_CLEARANCE_M + tip_to_bottom    # tip height, block carried
        carried_centre_z = carry_z - tip_to_bottom + peg_board.BLOCK_HEIGHT / 2
        handover = np.array([block[0], self.HANDOVER_Y, carried_centre_z])
        above2 = np.array([grasp2[0], grasp2[1], self.board.peg_top_z + self.PEG_CLEARANCE_M])
        lifted2 = np.array([grasp2[0], grasp2[1], carry_z])
        hover1 = handover + offset1 + np.array([0.0, 0.0, self.HOVER_M])
        release_centre_z = self.board.peg_top_z - self.RELEASE_DEPTH_M + peg_board.BLOCK_HEIGHT / 2
        up = np.array([0.0, 0.0, self.HOVER_M])

        def tip(obs, arm):
            return np.asarray(obs["observation"][7 * arm: 7 * arm + 3], np.float64)

        def block_error(obs, target):
            return np.asarray(target, np.float64) - np.asarray(obs["achieved_goal"], np.float64)

        def to_handover(obs):        # PSM2: bring the block's centre to the hand-over point
            return tip(obs, 1) + block_error(obs, handover)

        def over_grasp1(obs):        # PSM1: above its wall of the block, wherever the block now is
            return np.asarray(obs["achieved_goal"], np.float64) + offset1 + up

        def grasp1(obs):
            return np.asarray(obs["achieved_goal"], np.float64) + offset1

        def over_goal(obs):          # PSM1: block over the goal peg at carrying height
            g = np.asarray(obs["desired_goal"], np.float64)
            return tip(obs, 0) + block_error(obs, [g[0], g[1], carried_centre_z])

        def onto_peg(obs):
            g = np.asarray(obs["desired_goal"], np.float64)
            return tip(obs, 0) + block_error(obs, [g[0], g[1], release_centre_z])

        def stay(arm):
            return lambda obs: tip(obs, arm)

        def retreat(arm):
            return lambda obs: tip(obs, arm) + up

        def step(target, jaw, tol=1e-3, gain=None, **extra):
            s = {"target": target, "angle": yaw, "jaw": jaw, "tol": tol, **extra}
            if gain is not None:
                s["gain"] = gain
            return s

        waiting1 = step(hover1, OPEN, tol=1.0, angle_tol=10.0)
        holding2 = step(to_handover, CLOSE, tol=1.0, angle_tol=10.0)
        fast = self.TRANSIT_GAIN
        return [
            {"arms": (step(hover1, OPEN, gain=fast, tol=2e-3), step(above2, OPEN, gain=fast))},
            {"arms": (waiting1, step(grasp2, OPEN, tol=3e-4))},
            {"arms": (waiting1, step(grasp2, CLOSE, tol=2e-3)), "hold": 2},
            {"arms": (waiting1, step(lifted2, CLOSE, tol=2e-3))},
            {"arms": (waiting1, step(to_handover, CLOSE, gain=fast))},
            {"arms": (step(over_grasp1, OPEN), holding2)},
            {"arms": (step(grasp1, OPEN, tol=3e-4), holding2)},
            {"arms": (step(grasp1, CLOSE, tol=2e-3), holding2), "hold": 2},
            {"arms": (step(grasp1, CLOSE, tol=1.0, angle_tol=10.0), step(stay(1), OPEN, tol=1.0, angle_tol=10.0)),
             "hold": 1},
            {"arms": (step(over_goal, CLOSE, gain=fast), step(retreat(1), OPEN, tol=1.0, angle_tol=10.0))},
            {"arms": (step(onto_peg, CLOSE), step(stay(1), OPEN, tol=1.0, angle_tol=10.0))},
            {"arms": (step(stay(0), OPEN, tol=1.0, angle_tol=10.0), step(stay(1), OPEN, tol=1.0, angle_tol=10.0)),
             "hold": 1},
            {"arms": (step(retreat(0), OPEN, tol=1.0, angle_tol=10.0),
                      step(stay(1), OPEN, tol=1.0, angle_tol=10.0)), "hold": 2},
        ]

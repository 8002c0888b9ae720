"""PegTransfer: lift the red block off its peg and thread it onto the target peg."""

from __future__ import annotations

import numpy as np

from surrol_data.envs import peg_board, physics
from surrol_data.envs.psm_env import WORKSPACE, PsmEnv, wrap_angle
from surrol_data.envs.units import SUCCESS_TOLERANCE_M

OPEN, CLOSE = 0.5, -0.5


class PegTransfer(PsmEnv):
    TASK = "Transfer the red block from its peg onto the peg marked by the green target."
    ORACLE_GAIN = 0.7                # the reference's gain, used near the blocks and pegs
    TRANSIT_GAIN = 1.0               # full speed (1 cm per step) on the long moves above the pegs
    NUM_BLOCKS = 4
    START_PEGS = range(6, 12)        # blocks start on the lower cluster ...
    GOAL_PEGS = range(0, 6)          # ... and the goal is one of the two upper rows
    BLOCK_YAW_RANGE = np.deg2rad(30.0)
    HEIGHT_TOLERANCE_M = 0.004       # success: xy within 5 mm and |dz| within 4 mm of the goal peg's origin
    GRASP_DEPTH_M = 0.0025           # tip below the block's top face when grasping a wall
    PEG_CLEARANCE_M = 0.003          # tip above the peg tops on the approach; carried block bottom above them
    RELEASE_DEPTH_M = 0.003          # block bottom below the goal peg's top when the jaw opens (peg in the hole)

    # ------------------------------------------------------------------ scene
    def build_scene(self) -> None:
        self.board = peg_board.make_peg_board(self.client, visual=self.visual)
        shape = peg_board.block_collision_shape(self.client)
        colours = [peg_board.TARGET_RED] + [peg_board.OTHER_BLUE] * (self.NUM_BLOCKS - 1)
        self._block_specs = [peg_board.block_spec(self.client, shape, colour, visual=self.visual) for colour in colours]
        self.blocks: list[int] = []
        self.respawn_objects()

    def respawn_objects(self) -> None:
        for body in self.blocks:
            self.client.removeBody(body)
        self.blocks = [peg_board.spawn_block(self.client, spec) for spec in self._block_specs]
        # The red block is always the first; which peg it starts on is what the episode draws.
        self.object_id = self.blocks[0]

    def reset_task(self, rng):
        pegs = rng.permutation(list(self.START_PEGS))[: self.NUM_BLOCKS]
        yaws = rng.uniform(-self.BLOCK_YAW_RANGE, self.BLOCK_YAW_RANGE, size=self.NUM_BLOCKS)
        for body, peg, yaw in zip(self.blocks, pegs, yaws):
            peg_board.place_block_on_peg(self.client, body, self.board, int(peg), float(yaw))
        self.start_peg = int(pegs[0])
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2, 1]])
        return start, 0.0, physics.JAW_OPEN_RAD

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = super().reset(seed=seed, options=options)
        # The base class puts the red block to sleep; the others rest too, and only a touch may wake them.
        for body in self.blocks[1:]:
            self.client.changeDynamics(body, -1, activationState=physics.pb.ACTIVATION_STATE_SLEEP)
        return obs, info

    def sample_goal(self, rng):
        self.goal_peg = int(rng.choice(list(self.GOAL_PEGS)))
        return self.board.peg_positions[self.goal_peg].copy()

    # ------------------------------------------------------------------ observation and success
    def object_state(self):
        pos, rot = peg_board.block_pose(self.client, self.object_id)
        waypoint = pos + rot @ peg_board.BLOCK_WAYPOINTS[1]
        pitch = np.arcsin(np.clip(-rot[2, 0], -1.0, 1.0))
        euler = np.array([np.arctan2(rot[2, 1], rot[2, 2]), pitch, np.arctan2(rot[1, 0], rot[0, 0])])
        return pos, waypoint, euler

    def achieved_goal(self) -> np.ndarray:
        return peg_board.block_pose(self.client, self.object_id)[0]

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        d = np.asarray(achieved_goal, dtype=np.float64) - np.asarray(desired_goal, dtype=np.float64)
        return (np.linalg.norm(d[..., :2], axis=-1) < SUCCESS_TOLERANCE_M) & (np.abs(d[..., 2]) < self.HEIGHT_TOLERANCE_M)

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

"""The peg-board scene of PegTransfer and BiPegTransfer: threaded blocks on the board, the red one to move.

A mixin placed before the env base class (``class PegTransfer(PegBlocksScene, PsmEnv)``): it declares the
scene, the block placement, the goal peg and the success test that both peg tasks share.
"""

from __future__ import annotations

import numpy as np

from surrol_data.envs import peg_board, physics
from surrol_data.envs.numeric import norm
from surrol_data.envs.units import SUCCESS_TOLERANCE_M


class PegBlocksScene:
    NUM_BLOCKS = 4
    START_PEGS = range(6, 12)        # blocks start on the lower cluster ...
    GOAL_PEGS = range(0, 6)          # ... and the goal is one of the two upper rows
    BLOCK_YAW_RANGE = np.deg2rad(30.0)
    HEIGHT_TOLERANCE_M = 0.004       # success: xy within 5 mm and |dz| within 4 mm of the goal peg's origin

    def build_scene(self) -> None:
        self.board = peg_board.make_peg_board(self.client, visual=self.visual)
        shape = peg_board.block_collision_shape(self.client)
        colours = [peg_board.TARGET_RED] + [peg_board.OTHER_BLUE] * (self.NUM_BLOCKS - 1)
        self._block_specs = [peg_board.block_spec(self.client, shape, c, visual=self.visual) for c in colours]
        self.blocks: list[int] = []
        self.respawn_objects()

    def respawn_objects(self) -> None:
        for body in self.blocks:
            self.client.removeBody(body)
        self.blocks = [peg_board.spawn_block(self.client, spec) for spec in self._block_specs]
        self.object_id = self.blocks[0]   # the red one; the episode draws its peg

    def place_blocks(self, rng: np.random.Generator) -> None:
        """Thread the blocks on distinct random start pegs with random yaw."""
        pegs = rng.permutation(list(self.START_PEGS))[: self.NUM_BLOCKS]
        yaws = rng.uniform(-self.BLOCK_YAW_RANGE, self.BLOCK_YAW_RANGE, size=self.NUM_BLOCKS)
        for body, peg, yaw in zip(self.blocks, pegs, yaws):
            peg_board.place_block_on_peg(self.client, body, self.board, int(peg), float(yaw))
        self.start_peg = int(pegs[0])

    def dynamic_bodies(self) -> list[int]:
        return list(self.blocks)

    def sleep_blocks(self) -> None:
        # Resting blocks sleep until a jaw or another block touches them: their contacts with the pegs and
        # the board would otherwise be most of a step's physics.
        for body in self.blocks:
            self.client.changeDynamics(body, -1, activationState=physics.pb.ACTIVATION_STATE_SLEEP)

    WELD_ABOVE_GOAL_PEG_M = 0.01     # the weld forms once the squeezed block is this far above the goal peg's origin

    def grasp_lift_condition(self) -> bool:
        return self.achieved_goal()[2] > self.goal[2] + self.WELD_ABOVE_GOAL_PEG_M

    def sample_goal(self, rng):
        self.goal_peg = int(rng.choice(list(self.GOAL_PEGS)))
        return self.board.peg_positions[self.goal_peg].copy()

    def achieved_goal(self) -> np.ndarray:
        return peg_board.block_pose(self.client, self.object_id)[0]

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        d = np.asarray(achieved_goal, dtype=np.float64) - np.asarray(desired_goal, dtype=np.float64)
        return (norm(d[..., :2]) < SUCCESS_TOLERANCE_M) & (np.abs(d[..., 2]) < self.HEIGHT_TOLERANCE_M)

"""MatchBoardPanel: open the drawer by its handle, then put the block into the target cell (the paper's new task).

"The trainee needs to first grasp the drawer handle to open the drawer and then pick up a digit or alphabet block
to place it in the targeted grid, which is an advanced skills training task with sequential sub-tasks." The
drawer (see :mod:`surrol_data.envs.drawer`) slides on a prismatic joint with friction; its three cells are under
the cabinet's cover until it is pulled out. The block lies on the cover; the episode draws the block, its place
and turn, and the target cell.

Goals (6): the block's glyph centre and the handle's position; desired: the block lying in the target cell of the
fully opened drawer, and the handle where it is then. Success: the drawer open (handle within 5 mm of fully
out) and the block lying flat in the target cell (its centre within 8 mm across the cell, 12 mm along it and
1.5 mm of the floor height). ``info["subtasks"]`` reports the two sub-tasks in order.

Observation (23): the tip's 7 terms, the block's 12 (as MatchBoard), the handle's position and how far the drawer
is out (m).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from surrol_data.envs import drawer as dr
from surrol_data.envs import match_board as mb
from surrol_data.envs import physics
from surrol_data.envs.numeric import all_last, norm, vector_norm
from surrol_data.envs.psm_env import WORKSPACE, PsmEnv, wrap_angle
from surrol_data.envs.tasks.match_board import CLOSE, OPEN, GlyphBlockScene

SUBTASKS = ("open the drawer", "place the block in the target cell")


class MatchBoardPanel(GlyphBlockScene, PsmEnv):
    TASK = "Open the drawer by its handle, then place the block in the target cell."
    # Merged block boxes (match_board.MERGED_BLOCK_BOXES): the block resting in the drawer after the oracle's drop
    # (most of an episode) costs a third of what it did; block↔drawer/cabinet overlaps over 20 oracle episodes the
    # same (deepest 0.867 mm, median 0.848 mm, both ways).
    MERGED_BLOCKS = True
    CABINET_CENTRE = np.array([0.55, 0.0245, dr.table_z()])
    BLOCK_REGION = np.array([[0.53, 0.57], [0.020, 0.030]])       # on the cabinet's cover
    HANDLE_GRASP_DEPTH_M = 0.002
    PULL_SHORT_M = 0.001          # the oracle pulls to 1 mm short of the stop (pulling into it strains the weld)
    # A post held in the jaws and dragged off the drawer's axis slides in them: the grip lets the post move this
    # far in the hand before it is lost (a held block's limit is physics.GRASP_MAX_SLIP_M). People's pulls
    # wander off a straight line by a few millimetres.
    HANDLE_MAX_SLIP_M = 0.005
    OPEN_TOLERANCE_M = 0.005
    CELL_TOLERANCE_M = np.array([0.008, 0.012, 0.0015])
    CLEARANCE_M = 0.003           # carried block's bottom above the cover
    RELEASE_HEIGHT_M = 0.002      # block bottom above the cell floor when the jaw opens

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        box = lambda k: spaces.Box(-np.inf, np.inf, shape=(k,), dtype=np.float32)  # noqa: E731
        self.observation_space["observation"] = box(23)
        self.observation_space["achieved_goal"] = box(6)
        self.observation_space["desired_goal"] = box(6)
        self.goal = np.zeros(6)

    # ------------------------------------------------------------------ scene
    def build_scene(self) -> None:
        self.cabinet = dr.make_cabinet(self.client, self.CABINET_CENTRE, visual=self.visual)
        self._drawer_spec = dr.drawer_spec(self.client, self.cabinet, visual=self.visual)
        self.drawer = -1
        self.build_blocks()
        # Bodies exist from the start, so the first reset replaces them like every later one (and builds the
        # same world, bit for bit, as later resets with the same seed).
        self.respawn_objects()
        self.object_id = mb.spawn_block(self.client, self._block_specs[self.glyph], self.glyph)

    def respawn_objects(self) -> None:
        # The drawer is dynamic: a fresh one every episode (see PsmEnv.reset); the block comes in reset_task.
        if self.drawer >= 0:
            self.client.removeBody(self.drawer)
        self.drawer = dr.spawn_drawer(self.client, self._drawer_spec, self.cabinet)

    def reapply_scene_motors(self) -> None:
        dr.apply_friction(self.client, self.drawer)

    def reset_task(self, rng):
        self.target_cell = int(rng.integers(dr.CELLS))
        self.grasp.object_link = -1
        self.place_block_at_random(rng, self.cabinet.cover_top_z)
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2, 1]])
        return start, 0.0, physics.JAW_OPEN_RAD

    def sample_goal(self, rng):
        seat = self.cabinet.cell_floor_centre(self.target_cell, dr.TRAVEL) + [0.0, 0.0, mb.BLOCK_HEIGHT / 2]
        return np.concatenate([seat, self.cabinet.handle_position(dr.TRAVEL)])

    def goal_marker_position(self) -> np.ndarray:
        return self.goal[:3]

    # ------------------------------------------------------------------ grasping the handle or the block
    def handle_position(self) -> np.ndarray:
        return self.cabinet.handle_position(dr.opening(self.client, self.drawer))

    def step(self, action):
        if not self.grasp.attached:
            # The jaws grasp what they are at: the handle post or the block, whichever is nearer the tip.
            tip = self.tip_pose()[:3, 3]
            at_handle = vector_norm(self.handle_position() - tip) < vector_norm(self.grasp_point() - tip)
            self.grasp.object_id, self.grasp.object_link = (self.drawer, 0) if at_handle else (self.object_id, -1)
            self.grasp.max_slip_m = self.HANDLE_MAX_SLIP_M if at_handle else physics.GRASP_MAX_SLIP_M
        return super().step(action)

    def grasp_lift_condition(self) -> bool:
        # A handle is pulled, not lifted: its grip is welded at once.
        return self.grasp.object_id == self.drawer or self.block_lifted()

    # ------------------------------------------------------------------ observation and success
    def achieved_goal(self) -> np.ndarray:
        return np.concatenate([self.block_achieved_goal(), self.handle_position()])

    def subtasks_done(self, achieved_goal, desired_goal) -> tuple[np.ndarray, np.ndarray]:
        """(drawer open, block in the target cell), each (...,)."""
        e = np.asarray(achieved_goal, dtype=np.float64) - np.asarray(desired_goal, dtype=np.float64)
        opened = norm(e[..., 3:6]) < self.OPEN_TOLERANCE_M
        in_cell = all_last(np.abs(e[..., 0:3]) < self.CELL_TOLERANCE_M)
        return opened, in_cell

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        opened, in_cell = self.subtasks_done(achieved_goal, desired_goal)
        return opened & in_cell

    def object_state(self):
        return self.block_object_state()

    def observation_vector(self) -> np.ndarray:
        opening = dr.opening(self.client, self.drawer)
        return np.concatenate([super().observation_vector(), self.cabinet.handle_position(opening), [opening]])

    def _info(self, obs: dict) -> dict:
        opened, in_cell = self.subtasks_done(obs["achieved_goal"], obs["desired_goal"])
        info = super()._info(obs, success=opened & in_cell)   # (is_success is exactly this)
        info["subtasks"] = {SUBTASKS[0]: bool(opened), SUBTASKS[1]: bool(opened and in_cell)}
        return info

    # ------------------------------------------------------------------ oracle
    def plan_oracle(self):
        yaw = 0.0    # the jaws close across the post along x
        current = float(self.robot_state()[5])
        if abs(wrap_angle(yaw + np.pi - current)) < abs(wrap_angle(yaw - current)):
            yaw = float(wrap_angle(yaw + np.pi))
        depth = np.array([0.0, 0.0, self.HANDLE_GRASP_DEPTH_M])
        out = self.cabinet.handle_position(dr.TRAVEL - self.PULL_SHORT_M) - depth
        half_out = self.cabinet.handle_position((dr.TRAVEL - self.PULL_SHORT_M) / 2) - depth
        clear_z = self.cabinet.centre[2] + dr.HANDLE_TOP + 0.005

        # Targets at the handle follow it where it is (observation[19:22]): after a lost grip the drawer may
        # stand part-way out.
        def at_handle(lift):
            return lambda obs: np.asarray(obs["observation"][19:22], np.float64) - depth + [0.0, 0.0, lift]

        def stay(obs):
            return np.asarray(obs["observation"][:3], np.float64)

        def clear(obs):
            t = stay(obs)
            return np.array([t[0], t[1], clear_z])

        drawer = [
            {"target": at_handle(0.006), "yaw": yaw, "jaw": OPEN, "tol": 1.5e-3, "gain": 1.0},
            {"target": at_handle(0.0), "yaw": yaw, "jaw": OPEN, "tol": 3e-4},
            {"target": at_handle(0.0), "yaw": yaw, "jaw": CLOSE, "tol": 2e-3, "hold": 2},
            # Pulled in two strokes: a person's long straight pull wanders off the drawer's axis.
            {"target": half_out, "yaw": yaw, "jaw": CLOSE, "tol": 1.5e-3},
            {"target": out, "yaw": yaw, "jaw": CLOSE, "tol": 1e-3},
            {"target": stay, "yaw": yaw, "jaw": OPEN, "tol": 1.0, "yaw_tol": 10.0, "hold": 1},
            {"target": clear, "yaw": yaw, "jaw": OPEN, "tol": 2e-3},
        ]
        cover = self.cabinet.cover_top_z
        floor = self.cabinet.centre[2] + dr.FLOOR_TOP
        block = self.block_plan(yaw, lambda obs: obs["desired_goal"][:3], cover + self.CLEARANCE_M,
                                floor + self.RELEASE_HEIGHT_M, turn_to_seat=False)
        return drawer + block

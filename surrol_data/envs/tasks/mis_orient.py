"""MisOrient: roll the endoscope until its image is upright again (the "natural orientation")."""

from __future__ import annotations

import math

import numpy as np

from surrol_data.envs import ecm_kinematics as ekin
from surrol_data.envs.camera import CameraAxes, project, tracking_axes
from surrol_data.envs.ecm_env import EcmEnv, robot_state
from surrol_data.envs.physics import pb

ACTION_ROLL_RAD = np.deg2rad(3.0)      # 1 = 3° of roll per step
SUCCESS_TOLERANCE_RAD = 0.01
# Initial joints: uniform between these (the reference's: half the yaw/pitch/roll ranges, insertion 0–0.24 m).
JOINTS_LOW = np.array([np.deg2rad(-45.0), np.deg2rad(-22.5), 0.0, np.deg2rad(-45.0)])
JOINTS_HIGH = np.array([np.deg2rad(45.0), np.deg2rad(33.2), 0.24, np.deg2rad(45.0)])
# The upright view: the camera at all-zero joints.
NATURAL_JOINTS = (0.0, 0.0, 0.0, 0.0)
AXIS_LENGTH_M = 0.1
# Floor of coloured tiles (the reference's 9 × 16 textured cubes of SurRoL-v2), so the image shows its rotation.
TILES = (9, 16)
TILE_AREA = np.array([[-0.6, 0.4], [-0.8, 0.8]])
TILE_HALF_M = 0.02
TILE_COLOURS = ((0.90, 0.10, 0.29, 1.0), (0.24, 0.71, 0.29, 1.0), (1.0, 0.88, 0.10, 1.0), (0.0, 0.51, 0.78, 1.0),
                (0.96, 0.51, 0.19, 1.0), (0.88, 0.88, 0.88, 1.0))


def image_misorientation(current: CameraAxes, natural: CameraAxes) -> float:
    """Signed angle (rad) by which the current image must turn to show the floor as the natural view does.

    As in the reference: take the point where the current view axis meets the floor (z = 0), project it and
    10 cm steps along world x and y into both cameras, fit the 2-D linear map from the current image's
    axes to the natural image's, and return minus the angle of its rotation part (polar decomposition:
    for a 2×2 map with positive determinant the angle is atan2(m10 − m01, m00 + m11))."""
    eye, f = current.eye, current.forward
    t = -eye[2] / f[2] if f[2] < -1e-6 else 1.0      # looking up or level: use a point 1 m ahead instead
    p = (eye[0] + t * f[0], eye[1] + t * f[1], eye[2] + t * f[2])
    px = (p[0] + AXIS_LENGTH_M, p[1], p[2])
    py = (p[0], p[1] + AXIS_LENGTH_M, p[2])

    def axes_in(cam: CameraAxes):
        ox, oy, _ = project(cam, p)
        xx, xy, _ = project(cam, px)
        yx, yy, _ = project(cam, py)
        return xx - ox, xy - oy, yx - ox, yy - oy   # columns: image of world x, image of world y

    a00, a10, a01, a11 = axes_in(current)
    b00, b10, b01, b11 = axes_in(natural)
    # M = B · A⁻¹; A⁻¹ = adj(A) / det(A), and only the sign of det(A) matters for the angle.
    sign = 1.0 if a00 * a11 - a01 * a10 > 0 else -1.0
    m00 = sign * (b00 * a11 - b01 * a10)
    m01 = sign * (-b00 * a01 + b01 * a00)
    m10 = sign * (b10 * a11 - b11 * a10)
    m11 = sign * (-b10 * a01 + b11 * a00)
    return -math.atan2(m10 - m01, m00 + m11)


class MisOrient(EcmEnv):
    TASK = "Roll the endoscope so that its image is upright."
    ACTION_DIM = 1
    OBS_DIM = 9
    GOAL_DIM = 1
    ORACLE_GAIN = 0.3
    ACTION_ROTATION_RAD = ACTION_ROLL_RAD   # camera roll of one action unit (devices map hand roll through it)

    def build_scene(self) -> None:
        natural = [list(row) for row in ekin.ecm_fk_rows(*NATURAL_JOINTS)]
        world = self.ecm.world_T_rcm @ np.array(natural)
        self._natural = tracking_axes(world)
        if self.visual:
            xs = np.linspace(*TILE_AREA[0], TILES[0])
            ys = np.linspace(*TILE_AREA[1], TILES[1])
            shapes = [self.client.createVisualShape(pb.GEOM_BOX, halfExtents=[TILE_HALF_M] * 3, rgbaColor=c)
                      for c in TILE_COLOURS]
            for i, x in enumerate(xs):
                for j, y in enumerate(ys):
                    # A fixed, asymmetric colour pattern: any rotation of the image is visible in it.
                    shape = shapes[(i * 5 + j * 2 + (i * j) % 3) % len(shapes)]
                    self.client.createMultiBody(0.0, -1, shape, [float(x), float(y), TILE_HALF_M])

    def reset_task(self, rng):
        return tuple(rng.uniform(JOINTS_LOW, JOINTS_HIGH))

    def sample_goal(self, rng):
        return np.zeros(1)

    def apply_action(self, action) -> None:
        q = self.ecm.q
        self.ecm.command_joints((q[0], q[1], q[2], q[3] + float(action[0]) * ACTION_ROLL_RAD))

    def observe(self):
        w = self.ecm.eef_world
        misorientation = image_misorientation(tracking_axes(w), self._natural)
        return [*robot_state(self.ecm.eef_rcm), *ekin.euler_xyz(w)], [misorientation]

    def is_success(self, achieved_goal, desired_goal):
        return np.abs(np.asarray(achieved_goal)[..., 0] - np.asarray(desired_goal)[..., 0]) < SUCCESS_TOLERANCE_RAD

    def action_error(self, obs: dict) -> np.ndarray:
        """(dx, dy, dz, droll) in action units that would make the image upright (what a person aims for)."""
        error = float(obs["achieved_goal"][0] - obs["desired_goal"][0])
        return np.array([0.0, 0.0, 0.0, error / ACTION_ROLL_RAD])

    def oracle_action(self, obs: dict) -> np.ndarray:
        """Roll by 0.3 of the misorientation per step, at most 3° (a full action).

        The reference clips before applying its gain 0.3 (at most 0.9° per step), so misorientations above
        ~40° cannot be undone in 50 steps — most of its 12 % failures. Clipping after the gain keeps the same
        proportional law near the goal and turns at full speed far from it."""
        error = float(obs["achieved_goal"][0] - obs["desired_goal"][0])
        return np.array([np.clip(self.ORACLE_GAIN * error / ACTION_ROLL_RAD, -1.0, 1.0)], dtype=np.float32)

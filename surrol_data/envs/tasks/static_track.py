"""StaticTrack: steer the endoscope until a red cube sits in the middle of its image.

Also the base of ActiveTrack: the camera-velocity action, the tracking observation and the
image-based visual-servoing oracle live here.

Action (3,): a camera velocity in the camera's tracking frame (:func:`~surrol_data.envs.camera.tracking_axes`:
right, down, viewing direction of the image as it was rendered before schema camera version 2, a quarter turn
from today's picture — its right is image down, its down is image left; kept so that datasets and policies keep
their meaning; teleoperation maps the hand into the rendered image and converts);
1 = 1 mm of camera motion per 0.1 s step (1 cm/s). The ECM realises it about its RCM: the EEF target moves
by that much and the closed-form IK turns yaw/pitch and changes the insertion. A roll-compensation rate
(the reference's ``wz``) turns the roll back towards the orientation the camera had at reset, more firmly
as the target gets centred, so the image does not spin while the view swings.

Observation (10): EEF pose in the RCM frame (6), target in view (1), target centre in normalised image
coordinates of the tracking frame (2, ±1 at the image edges, +x right, +y down of that frame), wz (1). Achieved goal (cx, cy, wz); desired
goal zeros; success when ‖(cx, cy)‖ < 0.01 (the reference also "tests" wz against itself, which always
passes: wz is not part of success). The centre is the analytic projection of the cube's centre into the
reference's 256×256 camera — the reference uses the centroid of the cube's rendered mask and falls back to
this projection when the cube is out of view.
"""

from __future__ import annotations

import math

import numpy as np

from surrol_data.envs.camera import TAN_HALF_FOV, TRACKING_RESOLUTION, project
from surrol_data.envs.ecm_env import EcmEnv, robot_state
from surrol_data.envs.physics import pb

CAMERA_STEP_M = 0.001               # 1 = 1 mm of camera motion per step
CUBE_HALF_M = 0.05                  # the reference's cube: 10 cm, 0.1 kg
CUBE_MASS_KG = 0.1
DISTRACTORS = 18
TARGET_COLOUR = (230, 25, 75)
# Distractors come in pairs of one colour (the reference's palette after its red).
DISTRACTOR_COLOURS = ((60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 240, 240),
                      (240, 50, 230), (210, 245, 60), (250, 190, 190))
SUCCESS_TOLERANCE = 0.01            # normalised image units (1.3 px at 256²)
# Roll compensation: wz = WZ_GAIN · dz · exp(−WZ_DECAY · pixel error) (the reference's), roll step = −ROLL_PER_WZ · wz
# (dz grows with the roll joint, so the roll turns against wz).
WZ_GAIN = 25.0
WZ_DECAY = 0.1
ROLL_PER_WZ = 0.05
OUT_OF_VIEW = 5.0                   # reported centre of a target behind the camera (far outside ±1)


def rgba(colour_255) -> tuple[float, float, float, float]:
    return (*(c / 255.0 for c in colour_255), 1.0)


def heading_change(r0, r1) -> float:
    """Angle (rad) about world z between two camera rotations (rows), from their top-left 2×2 blocks —
    the reference's measure of how far the image has turned (its ``dz``). A camera looking down has a
    mirrored top view (negative determinant), hence atan(x / y) rather than atan2: it is right either way."""
    x = r0[0][0] * r1[1][0] - r0[1][0] * r1[0][0] + r0[0][1] * r1[1][1] - r0[1][1] * r1[0][1]
    y = r0[0][0] * r1[1][1] - r0[1][0] * r1[0][1] - r0[0][1] * r1[1][0] + r0[1][1] * r1[0][0]
    return math.atan(x / y) if y != 0.0 else math.copysign(math.pi / 2, x)


class StaticTrack(EcmEnv):
    TASK = "Centre the red cube in the endoscope image."
    ACTION_DIM = 3
    OBS_DIM = 10
    GOAL_DIM = 3
    INITIAL_JOINTS = (0.0, 0.0, 0.04, 0.0)
    CUBE_SCALE = 1.0
    AREA = np.array([[-0.5, 0.5], [-0.4, 0.4]])   # where cubes are placed (x, y), centre height = half size
    DISTRACTOR_AREA_SHIFT_X = 0.0
    MIN_SPACING_M = 0.15
    # Oracle: image-based visual servoing; move GAIN of the way to centring per step, scaled by OUTPUT_SCALE,
    # idle inside the dead zone (pixels at 256²) while wz is small.
    ORACLE_GAIN = 0.5
    ORACLE_OUTPUT_SCALE = 0.8
    ORACLE_DEADZONE_PX = 1.0
    ACTION_TRANSLATION_M = CAMERA_STEP_M   # camera motion of one action unit (devices map hand motion through it)

    def build_scene(self) -> None:
        half = CUBE_HALF_M * self.CUBE_SCALE
        self.cube_half = half
        c = self.client
        col = c.createCollisionShape(pb.GEOM_BOX, halfExtents=[half] * 3)
        colours = [TARGET_COLOUR] + [DISTRACTOR_COLOURS[i // 2 % len(DISTRACTOR_COLOURS)] for i in range(DISTRACTORS)]
        self.cubes = []
        for colour in colours:
            vis = c.createVisualShape(pb.GEOM_BOX, halfExtents=[half] * 3, rgbaColor=rgba(colour),
                                      specularColor=(0.05, 0.05, 0.05)) if self.visual else -1
            self.cubes.append(c.createMultiBody(CUBE_MASS_KG, col, vis, [0, 0, -1.0]))
        self.target_id = self.cubes[0]
        self.target_position = [0.0, 0.0, half]
        self._target_yaw = 0.0
        self._reference_rotation = None
        self._centre = (0.0, 0.0)
        self.wz = 0.0

    # ------------------------------------------------------------------ layout
    def place_cubes(self, rng, target_xy=None) -> None:
        """Target first (at ``target_xy`` or sampled), then distractors at least MIN_SPACING_M from all placed."""
        half = self.cube_half
        placed = []
        area = self.AREA.copy()
        for k, body in enumerate(self.cubes):
            if k == 1:
                area[0, 0] += self.DISTRACTOR_AREA_SHIFT_X
            yaw = rng.uniform(-np.pi, np.pi)
            if k == 0 and target_xy is not None:
                xy = np.asarray(target_xy, dtype=np.float64)
            else:
                for _ in range(100):   # the reference's rejection sampling (100 tries, then the last draw)
                    xy = rng.uniform(area[:, 0], area[:, 1])
                    if all(np.hypot(*(xy - p)) >= self.MIN_SPACING_M for p in placed):
                        break
            placed.append(xy)
            self.client.resetBasePositionAndOrientation(body, [float(xy[0]), float(xy[1]), half],
                                                        self.client.getQuaternionFromEuler([0, 0, yaw]))
            if k == 0:
                self.target_position = [float(xy[0]), float(xy[1]), half]
                self._target_yaw = float(yaw)

    def reset_task(self, rng):
        self.place_cubes(rng)
        return self.INITIAL_JOINTS

    def sample_goal(self, rng):
        return np.zeros(3)

    def after_reset(self) -> None:
        self._reference_rotation = [row[:3] for row in self.ecm.eef_world[:3]]
        self.wz = 0.0
        self._centre = self._project_target()[:2]

    # ------------------------------------------------------------------ action and observation
    def apply_action(self, action) -> None:
        m = self.ecm.eef_rcm
        cx, cy = self._centre
        pixel_error = TRACKING_RESOLUTION * math.hypot(cx, cy)   # the reference measures it at 256 px per unit
        dz = heading_change(self._reference_rotation, self.ecm.eef_world)
        self.wz = WZ_GAIN * dz * math.exp(-WZ_DECAY * pixel_error)
        # Camera axes in the RCM frame: right = −x4, down = −y4, forward = z4.
        vr, vd, vf = (float(a) * CAMERA_STEP_M for a in action)
        target = [m[i][3] - vr * m[i][0] - vd * m[i][1] + vf * m[i][2] for i in range(3)]
        self.ecm.command_eef_position_rcm(target, self.ecm.q[3] - ROLL_PER_WZ * self.wz)

    def action_axes(self) -> np.ndarray:
        axes = self.ecm.tracking_axes()          # the action is a camera velocity in the tracking frame
        return np.column_stack([axes.right, axes.down, axes.forward])

    def _project_target(self) -> tuple[float, float, bool]:
        x, y, depth = project(self.ecm.tracking_axes(), self.target_position)
        if depth <= 0.0:
            return OUT_OF_VIEW, OUT_OF_VIEW, False
        x, y = max(-OUT_OF_VIEW, min(OUT_OF_VIEW, x)), max(-OUT_OF_VIEW, min(OUT_OF_VIEW, y))
        return x, y, abs(x) <= 1.0 and abs(y) <= 1.0

    def observe(self):
        cx, cy, in_view = self._project_target()
        self._centre = (cx, cy)
        self.in_view = in_view
        return [*robot_state(self.ecm.eef_rcm), float(in_view), cx, cy, self.wz], [cx, cy, self.wz]

    def sync_bodies(self) -> None:
        self.client.resetBasePositionAndOrientation(self.target_id, self.target_position,
                                                    self.client.getQuaternionFromEuler([0, 0, self._target_yaw]))

    def is_success(self, achieved_goal, desired_goal):
        d = np.linalg.norm(np.asarray(achieved_goal)[..., :2] - np.asarray(desired_goal)[..., :2], axis=-1)
        return d < SUCCESS_TOLERANCE

    # ------------------------------------------------------------------ oracle
    def action_error(self, obs: dict) -> np.ndarray:
        """(right, down, forward, roll) in action units that would centre the target: the sideways camera motion
        that turns the view onto it (see :meth:`oracle_action`); what a person watching the image aims for."""
        state = obs["observation"]
        cx, cy = float(state[7]), float(state[8])
        lever = math.sqrt(float(state[0]) ** 2 + float(state[1]) ** 2 + float(state[2]) ** 2)
        return np.array([math.atan(cx * TAN_HALF_FOV) * lever / CAMERA_STEP_M,
                         math.atan(cy * TAN_HALF_FOV) * lever / CAMERA_STEP_M, 0.0, 0.0])

    def oracle_action(self, obs: dict) -> np.ndarray:
        """Image-based visual servoing: turn the view towards the target by ORACLE_GAIN of its angular offset.

        The offset angle of the target from the view axis is atan(c·tan 30°) per image axis; the EEF sits
        ‖p‖ from the RCM, so turning the endoscope by that angle moves the camera ‖p‖·angle sideways."""
        state = obs["observation"]
        cx, cy, wz = float(state[7]), float(state[8]), float(state[9])
        if TRACKING_RESOLUTION * math.hypot(cx, cy) < self.ORACLE_DEADZONE_PX and abs(wz) < 0.1:
            return np.zeros(3, dtype=np.float32)
        lever = math.sqrt(float(state[0]) ** 2 + float(state[1]) ** 2 + float(state[2]) ** 2)
        a = np.array([math.atan(cx * TAN_HALF_FOV), math.atan(cy * TAN_HALF_FOV), 0.0]) * lever / CAMERA_STEP_M
        a *= self.ORACLE_GAIN
        a = a / max(1.0, np.abs(a).max()) * self.ORACLE_OUTPUT_SCALE
        return a.astype(np.float32)

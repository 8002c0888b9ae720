"""The dVRK endoscope camera manipulator (ECM): joint state, PD motion with limits, and its camera.

The ECM touches nothing (it has no collision shapes in the reference's tasks either), so its motion is not
left to PyBullet's solver: each control period applies PyBullet's own position-motor law — per 1/240 s
step the joint velocity is ``Kp·(target − q)/dt`` clamped to the joint's velocity limit — integrated in
closed form (:func:`pd_with_limits`), which makes a step a few microseconds instead of 24 solver steps.
``tests/test_ecm.py`` checks the closed form against PyBullet's motor on a real multibody.

When a scene is rendered the ECM also exists as a visual-only, non-colliding shaft in the PyBullet world,
moved to the computed pose before each render (:meth:`Ecm.sync_visual`).
"""

from __future__ import annotations

import math

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import ecm_kinematics as ekin
from surrol_data.envs import kinematics as psm_kin
from surrol_data.envs import physics
from surrol_data.envs.camera import EndoscopeCamera, camera_axes, make_camera, tracking_axes
from surrol_data.envs.psm import matrix_to_quat

# ECM base (URDF base link) → RCM: 0.6126 m forward, 0.1016 m up, turned −90° about z (the reference's URDF).
BASE_T_RCM = psm_kin.pose_from([0.6126, 0.0, 0.1016], psm_kin.rot_z3(-np.pi / 2))
# The reference's ECM tasks: base at (−0.05, 0, 1.0024) pitched 30° about y; the RCM lands at (0.531, 0, 0.784).
ECM_TASK_BASE_POSITION = (-0.05, 0.0, 1.0024)
ECM_TASK_BASE_PITCH_RAD = np.deg2rad(30.0)
# SurRoL-v2 puts an ECM over every PSM scene as the operator's camera: base (0.15, 0, 0.8524), joints
# (0, 0.6, 0.04, 0). From there the 60° view showed the whole table, the void beyond it and the table's front
# edge, with the tray in a quarter of the image. The endoscope keeps that base but is aimed at the centre of the
# tasks' workspace (1 cm above the table top) and inserted until it is 15 cm from it, as a surgeon frames the
# field: the tray or board fills a 640×480 image edge to edge, no void or table edge in view, and the tools stay
# in view through every oracle episode (tests/test_camera_frame.py checks all three).
PSM_SCENE_BASE_POSITION = (0.15, 0.0, 0.8524)
PSM_SCENE_VIEW_TARGET = (0.55, 0.0, 0.685)
PSM_SCENE_VIEW_DISTANCE_M = 0.15

_SHAFT_RADIUS_M = 0.005
_SHAFT_LENGTH_M = 0.30
_SHAFT_COLOUR = (0.85, 0.85, 0.82, 1.0)


def rot_y3(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def world_T_rcm_from_base(base_position, base_pitch_rad: float = 0.0) -> np.ndarray:
    """World pose of the RCM frame for an ECM base at ``base_position`` (real metres) pitched about y."""
    return psm_kin.pose_from(base_position, rot_y3(base_pitch_rad)) @ BASE_T_RCM


def pd_with_limits(q: float, target: float, gain: float, max_step: float, steps: int) -> float:
    """Position after ``steps`` motor steps of q ← q + clamp(gain·(target − q), ±max_step), in closed form.

    While the proportional step exceeds ``max_step`` the error shrinks by ``max_step`` per step; after that
    it shrinks by the factor (1 − gain) per step."""
    error = target - q
    if error == 0.0:
        return q
    size = abs(error)
    if size * gain > max_step:
        linear = min(steps, math.ceil((size - max_step / gain) / max_step))
        size -= linear * max_step
        steps -= linear
    return target - math.copysign(size * (1.0 - gain) ** steps, error)


class Ecm:
    """One ECM. Positions in and out are real metres; ``world_T_rcm`` is fixed at construction."""

    def __init__(self, world_T_rcm: np.ndarray, client=None, scene_scale: float = 1.0, visual: bool = False):
        self.world_T_rcm = np.asarray(world_T_rcm, dtype=np.float64)
        self._r = self.world_T_rcm[:3, :3].tolist()
        self._o = self.world_T_rcm[:3, 3].tolist()
        self.rcm_T_world = np.linalg.inv(self.world_T_rcm)
        self.client = client
        self.scene_scale = float(scene_scale)
        self.q = [0.0, 0.0, 0.05, 0.0]
        self.q_target = list(self.q)
        self._max_step = [v * physics.ECM_CONTROL_PERIOD_S / physics.ECM_SUBSTEPS for v in physics.ECM_MAX_VELOCITY]
        self.shaft = -1
        if visual:
            if client is None:
                raise ValueError("a visual ECM needs the PyBullet client of the scene it is drawn in")
            s = self.scene_scale
            vis = client.createVisualShape(pb.GEOM_CYLINDER, radius=_SHAFT_RADIUS_M * s, length=_SHAFT_LENGTH_M * s,
                                           visualFramePosition=[0, 0, -_SHAFT_LENGTH_M * s / 2],
                                           rgbaColor=_SHAFT_COLOUR)
            self.shaft = client.createMultiBody(0.0, -1, vis, [0, 0, 0])
        self._refresh()

    # ------------------------------------------------------------------ state
    def reset_joints(self, q) -> None:
        q = [float(v) for v in q]
        if not ekin.within_limits(q):
            raise ValueError(f"ECM joints {q} are outside the limits {ekin.ECM_LOWER} … {ekin.ECM_UPPER}")
        self.q = q
        self.q_target = list(q)
        self._refresh()

    def command_joints(self, q) -> bool:
        """Set joint targets. Out-of-limit targets are refused (the arm keeps its target), as for the PSM."""
        if not ekin.within_limits(q):
            return False
        self.q_target = [float(v) for v in q]
        return True

    def command_eef_position_rcm(self, p_rcm, roll: float) -> bool:
        """Set joint targets that bring the EEF to ``p_rcm`` (RCM frame) with roll ``roll``."""
        return self.command_joints(ekin.ecm_ik_position(p_rcm, roll))

    def advance(self, substeps: int = physics.ECM_SUBSTEPS) -> None:
        """Move the joints through ``substeps`` motor steps towards their targets (one control period by default)."""
        gain = physics.ECM_POSITION_GAIN
        self.q = [pd_with_limits(q, t, gain, m, substeps) for q, t, m in zip(self.q, self.q_target, self._max_step)]
        self._refresh()

    def _refresh(self) -> None:
        # Cache the EEF pose in both frames as nested float lists: every step reads them several times.
        m = ekin.ecm_fk_rows(*self.q)
        self.eef_rcm = m
        r, o = self._r, self._o
        w = [[r[i][0] * m[0][j] + r[i][1] * m[1][j] + r[i][2] * m[2][j] for j in range(4)] for i in range(3)]
        for i in range(3):
            w[i][3] += o[i]
        w.append([0.0, 0.0, 0.0, 1.0])
        self.eef_world = w

    # ------------------------------------------------------------------ poses
    def eef_pose_world(self) -> np.ndarray:
        return np.array(self.eef_world)

    def eef_pose_rcm(self) -> np.ndarray:
        return np.array(self.eef_rcm)

    def eef_position_world(self) -> list[float]:
        w = self.eef_world
        return [w[0][3], w[1][3], w[2][3]]

    def tip_position_world(self) -> list[float]:
        """The reference's ECM tip link: 2 cm beyond the EEF along the view axis (where tip paths are measured)."""
        w, d = self.eef_world, ekin.CAMERA_TARGET_OFFSET_M
        return [w[i][3] + d * w[i][2] for i in range(3)]

    def world_to_rcm(self, p_world) -> list[float]:
        m = self.rcm_T_world
        x, y, z = (float(v) for v in p_world)
        return [m[i, 0] * x + m[i, 1] * y + m[i, 2] * z + m[i, 3] for i in range(3)]

    def rcm_to_world(self, p_rcm) -> list[float]:
        r, o = self._r, self._o
        x, y, z = (float(v) for v in p_rcm)
        return [r[i][0] * x + r[i][1] * y + r[i][2] * z + o[i] for i in range(3)]

    def camera_axes(self):
        """The image's axes (what is rendered; see :func:`surrol_data.envs.camera.camera_axes`)."""
        return camera_axes(self.eef_world)

    def tracking_axes(self):
        """The ECM tasks' observation and action frame (:func:`surrol_data.envs.camera.tracking_axes`)."""
        return tracking_axes(self.eef_world)

    def sync_visual(self) -> None:
        """Move the visual shaft to the current pose (only scenes that render have one)."""
        if self.shaft < 0:
            return
        w = np.array(self.eef_world)
        self.client.resetBasePositionAndOrientation(self.shaft, (w[:3, 3] * self.scene_scale).tolist(),
                                                    matrix_to_quat(w[:3, :3]))


def aimed_joints(world_T_rcm: np.ndarray, target, distance_m: float) -> tuple[float, float, float, float]:
    """ECM joints (roll 0) that point the endoscope from its RCM at ``target`` (world, real metres) with the
    lens ``distance_m`` short of it."""
    rcm = world_T_rcm[:3, 3]
    direction = np.asarray(target, dtype=np.float64) - rcm
    length = float(np.linalg.norm(direction))
    eye = rcm + (length - distance_m) * direction / length
    p_rcm = (np.linalg.inv(world_T_rcm) @ np.append(eye, 1.0))[:3]
    q = ekin.ecm_ik_position(p_rcm, 0.0)
    if not ekin.within_limits(q):
        raise ValueError(f"the ECM cannot look at {tuple(target)} from {distance_m} m: joints {q} are outside its "
                         "limits")
    return q


PSM_SCENE_JOINTS = aimed_joints(world_T_rcm_from_base(PSM_SCENE_BASE_POSITION), PSM_SCENE_VIEW_TARGET,
                                PSM_SCENE_VIEW_DISTANCE_M)


def scene_endoscope_pose() -> list[list[float]]:
    """EEF pose (4×4 nested rows, world, real metres) of the still endoscope over every PSM scene."""
    ecm = Ecm(world_T_rcm_from_base(PSM_SCENE_BASE_POSITION))
    ecm.reset_joints(PSM_SCENE_JOINTS)
    return ecm.eef_world


class SceneEndoscope:
    """A still ECM over a PSM scene with its camera: the endoscope view that ``camera=True`` adds to the
    observation of PSM envs (SurRoL-v2's base, aimed at the workspace: :data:`PSM_SCENE_JOINTS`). The bimanual
    env uses it the same way:
    ``SceneEndoscope(client, camera_size, scene_scale=SCALING)`` then ``.image()`` in its observation."""

    def __init__(self, client, size: tuple[int, int] = (128, 128), scene_scale: float = 1.0,
                 base_position=PSM_SCENE_BASE_POSITION, joints=PSM_SCENE_JOINTS, renderer: str = "tiny",
                 camera=None):
        self.ecm = Ecm(world_T_rcm_from_base(base_position), client=client, scene_scale=scene_scale, visual=True)
        self.ecm.reset_joints(joints)
        self.ecm.sync_visual()
        # ``camera``: keep an existing camera of this client (a rebuilt world need not rebuild its renderer).
        self.camera = camera or make_camera(client, size, scene_scale=scene_scale, renderer=renderer)

    @property
    def size(self) -> tuple[int, int]:
        return self.camera.width, self.camera.height

    def image(self) -> np.ndarray:
        """uint8 (H, W, 3) RGB from the endoscope."""
        return self.camera.render(self.ecm.eef_world).rgb

    def render(self, depth: bool = False, segmentation: bool = False):
        return self.camera.render(self.ecm.eef_world, depth=depth, segmentation=segmentation)

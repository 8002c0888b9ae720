"""dVRK PSM kinematics: modified-DH forward kinematics and a closed-form inverse.

All lengths here are *real* metres (multiply by ``units.SCALING`` for the simulation). Poses are 4×4
homogeneous matrices expressed in the remote-centre-of-motion (RCM) frame, whose origin is the RCM
point; with all joints at zero the shaft points along −z of that frame.

Joint order: outer yaw, outer pitch, insertion (prismatic, m), tool roll, wrist pitch, wrist yaw.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

# Modified DH rows (alpha_{i-1}, a_{i-1}, theta offset, d offset, prismatic?) — dVRK large needle driver.
PSM_DH = (
    (+np.pi / 2, 0.0, +np.pi / 2, 0.0, False),
    (-np.pi / 2, 0.0, -np.pi / 2, 0.0, False),
    (+np.pi / 2, 0.0, 0.0, -0.4318, True),
    (0.0, 0.0, 0.0, 0.4162, False),
    (-np.pi / 2, 0.0, -np.pi / 2, 0.0, False),
    (-np.pi / 2, 0.0091, -np.pi / 2, 0.0, False),
)
# Wrist yaw frame → tool tip: 10.2 mm along the wrist-yaw y axis, axes permuted to the dVRK tip convention.
TOOL_TIP_OFFSET = np.array([[0.0, -1.0, 0.0, 0.0],
                            [0.0, 0.0, 1.0, 0.0102],
                            [-1.0, 0.0, 0.0, 0.0],
                            [0.0, 0.0, 0.0, 1.0]])
WRIST_LENGTH = 0.0091
TIP_LENGTH = 0.0102
SHAFT_END_OFFSET = 0.4318 - 0.4162   # insertion at which the wrist-pitch axis sits on the RCM

# Software joint limits (rad, m) and the jaw (rad).
PSM_LOWER = np.deg2rad([-91.0, -53.0, 0.0, -260.0, -80.0, -80.0])
PSM_UPPER = np.deg2rad([91.0, 53.0, 0.0, 260.0, 80.0, 80.0])
PSM_LOWER[2], PSM_UPPER[2] = 0.0, 0.24
JAW_LIMITS = (np.deg2rad(-20.0), np.deg2rad(80.0))


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


# FK and IK run every step: fresh matrices are copies of the identity with the entries set (math's sin/cos give
# numpy's values), and products are ``a.dot(b)``, which computes exactly what ``a @ b`` does (the same BLAS
# kernel, checked bit for bit) at a third of the call overhead on 4×4 arrays.
_EYE4 = np.eye(4)
_EYE3 = np.eye(3)


def _set_rot_z(m: np.ndarray, a: float) -> np.ndarray:
    """Write a rotation by ``a`` about z into the upper-left 2×2 block of identity matrix ``m``; returns ``m``."""
    c, s = math.cos(a), math.sin(a)
    m[0, 0] = c
    m[0, 1] = -s
    m[1, 0] = s
    m[1, 1] = c
    return m


def _rot_z(a: float) -> np.ndarray:
    return _set_rot_z(_EYE4.copy(), a)


def _trans(x: float = 0.0, z: float = 0.0) -> np.ndarray:
    t = _EYE4.copy()
    t[0, 3], t[2, 3] = x, z
    return t


def dh_fixed_transform(row) -> np.ndarray:
    """The joint-independent part of a modified-DH row: RotX(alpha) · TransX(a) · (offset about/along z)."""
    alpha, a, theta_off, d_off, _ = row
    return _rot_x(alpha) @ _trans(x=a) @ _rot_z(theta_off) @ _trans(z=d_off)


def dh_joint_transform(row, q: float) -> np.ndarray:
    prismatic = row[4]
    return _trans(z=q) if prismatic else _rot_z(q)


_PSM_FIXED = tuple(dh_fixed_transform(row) for row in PSM_DH)
# The chain starts with identity @ fixed_1: a constant, computed once (the same product, so the same bits).
_PSM_FIRST_FIXED = np.eye(4) @ _PSM_FIXED[0]
_PSM_PRISMATIC = tuple(bool(row[4]) for row in PSM_DH)


def _psm_chain(q, n: int) -> list[np.ndarray]:
    """Frames 1..n of the PSM in the RCM frame for the first ``n`` joints of ``q``."""
    frames = []
    t = None
    for i in range(n):
        joint = _trans(z=q[i]) if _PSM_PRISMATIC[i] else _rot_z(q[i])
        t = (_PSM_FIRST_FIXED if i == 0 else t.dot(_PSM_FIXED[i])).dot(joint)
        frames.append(t)
    return frames


def psm_link_frames(q) -> list[np.ndarray]:
    """Frames 1..6 of the PSM in the RCM frame (frame 6 = wrist yaw)."""
    return _psm_chain(q, len(PSM_DH))


def psm_fk(q) -> np.ndarray:
    """Tool-tip pose (4×4, RCM frame, metres) for joints ``q`` (6,)."""
    return _psm_chain(q, len(PSM_DH))[-1].dot(TOOL_TIP_OFFSET)


_TIP_ROTATION_T = TOOL_TIP_OFFSET[:3, :3].T
_TIP_OFFSET_POSITION = TOOL_TIP_OFFSET[:3, 3]
_PSM_LOWER_TOLERANT = (PSM_LOWER - 1e-9).tolist()
_PSM_UPPER_TOLERANT = (PSM_UPPER + 1e-9).tolist()


class IKResult(NamedTuple):
    q: np.ndarray
    within_limits: bool


def psm_ik(tip_pose: np.ndarray) -> IKResult:
    """Closed-form inverse kinematics of the PSM tool tip (the natural, wrist-outward solution).

    Geometry: the wrist-yaw origin p6 and axis z6 follow from the tip pose. The shaft passes through the
    RCM (origin) and the wrist-pitch point p5, and p5 lies 9.1 mm from p6 in the plane through the
    origin spanned by the shaft and z6 — so p5 is p6 moved towards the RCM, perpendicular to z6.
    Insertion is |p5| plus the shaft-end offset; the outer yaw/pitch follow from the shaft direction and
    the wrist joints from R3ᵀ·R6 (the DH structure makes them an Euler-like extraction).
    """
    # (Called every step. The matrix products stay numpy's (its BLAS kernel fuses multiply-adds, which plain
    # floats cannot repeat); the 3-vector and scalar steps are plain floats: the same operations in the same
    # order as numpy's (its dot products of 3-vectors sum left to right; math's sqrt, asin and atan2 are the C
    # library's, as numpy's are here), without numpy's per-call overhead. tests/test_env_fast_paths.py checks the
    # bits against the numpy form.)
    r6 = tip_pose[:3, :3].dot(_TIP_ROTATION_T)
    px, py, pz = (tip_pose[:3, 3] - r6.dot(_TIP_OFFSET_POSITION)).tolist()
    zx, zy, zz = r6[:, 2].tolist()
    d = px * zx + py * zy + pz * zz
    rx, ry, rz = px - d * zx, py - d * zy, pz - d * zz
    radial_norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    if radial_norm < 1e-9:
        raise ValueError("tip pose is singular for the PSM: the wrist-yaw axis passes through the RCM")
    px -= WRIST_LENGTH * rx / radial_norm
    py -= WRIST_LENGTH * ry / radial_norm
    pz -= WRIST_LENGTH * rz / radial_norm
    depth = math.sqrt(px * px + py * py + pz * pz)
    sx, sy, sz = px / depth, py / depth, pz / depth
    q3 = depth + SHAFT_END_OFFSET
    q2 = math.asin(min(max(-sy, -1.0), 1.0))
    q1 = math.atan2(sx, -sz)
    r3 = _psm_chain((q1, q2, q3), 3)[2][:3, :3]
    m = r3.T.dot(r6).tolist()
    q5 = math.asin(min(max(-m[2][2], -1.0), 1.0))
    q4 = math.atan2(m[1][2], m[0][2])
    q6 = math.atan2(m[2][0], m[2][1])
    values = (q1, q2, q3, q4, q5, q6)
    ok = all(lo <= v <= hi for v, lo, hi in zip(values, _PSM_LOWER_TOLERANT, _PSM_UPPER_TOLERANT))
    return IKResult(np.array(values), ok)


def pose_from(position, rotation) -> np.ndarray:
    t = _EYE4.copy()
    t[:3, :3] = rotation
    t[:3, 3] = position
    return t


def euler_xyz(rotation: np.ndarray) -> np.ndarray:
    """Extrinsic x-y-z Euler angles (roll, pitch, yaw) in rad of a rotation matrix: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    # (math's atan2 and asin on plain floats: numpy's values, without its per-call overhead; see psm_ik.)
    r = rotation.tolist()
    return np.array([math.atan2(r[2][1], r[2][2]), math.asin(min(max(-r[2][0], -1.0), 1.0)),
                     math.atan2(r[1][0], r[0][0])])


def rot_z3(a: float) -> np.ndarray:
    return _set_rot_z(_EYE3.copy(), a)


def tool_down_rotation(yaw: float) -> np.ndarray:
    """World rotation of the tip frame with the tool pointing straight down (tip z = −world z) and yaw ``yaw``.

    The tip frame's x axis is the jaw-opening direction; yaw rotates it about the world vertical.
    """
    down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    return rot_z3(yaw) @ down


def yaw_of_tool_down(rotation: np.ndarray) -> float:
    """Inverse of :func:`tool_down_rotation` for the yaw (angle of the tip x axis about world z)."""
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))

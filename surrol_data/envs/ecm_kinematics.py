"""dVRK ECM (endoscope camera manipulator) kinematics: modified-DH forward kinematics, closed-form inverse.

All lengths are *real* metres. Poses are expressed in the remote-centre-of-motion (RCM) frame; with all
joints at zero the endoscope points along −z of that frame. Joint order: yaw, pitch, insertion (prismatic,
m), roll. Frame 4 (the "EEF", where the endoscope's optics sit) is the dVRK tip convention of the ECM; the
camera looks along its z axis with its y axis as the image's up direction (the reference renders from the
EEF towards a point 2 cm ahead, up vector = the URDF end link's x axis, which is DH y4).

The chain is short enough to write out: with cᵢ = cos qᵢ, sᵢ = sin qᵢ the frame-3 axes are
x3 = (−s1 s2, −c2, c1 s2), y3 = (−c1, 0, −s1), z3 = (s1 c2, −s2, −c1 c2); frame 4 is frame 3 rolled by q4
about z3 and sits ``q3 + INSERTION_OFFSET_M`` along z3 from the RCM. :func:`ecm_fk` evaluates that in
plain floats (the envs call it every step); :func:`ecm_fk_dh` is the textbook DH product, kept as the
definition the fast form is tested against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from surrol_data.envs import kinematics as psm_kin

# Modified DH rows (alpha_{i-1}, a_{i-1}, theta offset, d offset, prismatic?) — dVRK ECM.
ECM_DH = (
    (+np.pi / 2, 0.0, +np.pi / 2, 0.0, False),
    (-np.pi / 2, 0.0, -np.pi / 2, 0.0, False),
    (+np.pi / 2, 0.0, 0.0, -0.3822, True),
    (0.0, 0.0, 0.0, 0.3829, False),
)
# Insertion 0 puts the EEF this far beyond the RCM (the two DH d offsets do not cancel).
INSERTION_OFFSET_M = 0.3829 - 0.3822
# The reference's camera target point ("tip link"): 2 cm ahead of the EEF along the view axis.
CAMERA_TARGET_OFFSET_M = 0.02

# Software joint limits (rad, m). The reference leaves roll unbounded in software; its URDF bounds it to ±90°,
# and PyBullet enforces URDF limits, so ±90° is what the reference's ECM actually reaches.
ECM_LOWER = np.array([np.deg2rad(-90.0), np.deg2rad(-45.0), -0.01, np.deg2rad(-90.0)])
ECM_UPPER = np.array([np.deg2rad(90.0), np.deg2rad(66.4), 0.254, np.deg2rad(90.0)])
_LOWER = tuple(float(v) for v in ECM_LOWER)
_UPPER = tuple(float(v) for v in ECM_UPPER)
_TOLERANCE = 1e-9


def ecm_fk_dh(q) -> np.ndarray:
    """EEF pose (4×4, RCM frame) as the product of the modified-DH link transforms."""
    t = np.eye(4)
    for row, qi in zip(ECM_DH, q):
        t = t @ psm_kin.dh_fixed_transform(row) @ psm_kin.dh_joint_transform(row, float(qi))
    return t


def ecm_fk(q) -> np.ndarray:
    """EEF pose (4×4, RCM frame, metres) for joints ``q`` (4,)."""
    return np.array(ecm_fk_rows(*(float(v) for v in q)))


def ecm_fk_rows(q1: float, q2: float, q3: float, q4: float) -> list[list[float]]:
    """:func:`ecm_fk` as nested lists of floats (no array allocation: cheap enough to call every step)."""
    c1, s1, c2, s2, c4, s4 = math.cos(q1), math.sin(q1), math.cos(q2), math.sin(q2), math.cos(q4), math.sin(q4)
    x3 = (-s1 * s2, -c2, c1 * s2)
    y3 = (-c1, 0.0, -s1)
    z3 = (s1 * c2, -s2, -c1 * c2)
    x4 = [c4 * a + s4 * b for a, b in zip(x3, y3)]
    y4 = [-s4 * a + c4 * b for a, b in zip(x3, y3)]
    d = q3 + INSERTION_OFFSET_M
    return [[x4[0], y4[0], z3[0], d * z3[0]],
            [x4[1], y4[1], z3[1], d * z3[1]],
            [x4[2], y4[2], z3[2], d * z3[2]],
            [0.0, 0.0, 0.0, 1.0]]


@dataclass(frozen=True)
class EcmIKResult:
    q: np.ndarray
    within_limits: bool


def within_limits(q) -> bool:
    return all(lo - _TOLERANCE <= v <= hi + _TOLERANCE for v, lo, hi in zip(q, _LOWER, _UPPER))


def ecm_ik_position(p_rcm, roll: float) -> tuple[float, float, float, float]:
    """Joints that put the EEF at ``p_rcm`` (RCM frame, metres) with roll ``roll``: the endoscope axis
    passes through the RCM, so its direction fixes yaw and pitch and its length fixes the insertion.
    Returns a plain tuple (no limit check; see :func:`within_limits`)."""
    x, y, z = float(p_rcm[0]), float(p_rcm[1]), float(p_rcm[2])
    r = math.sqrt(x * x + y * y + z * z)
    if r < 1e-9:
        raise ValueError("ECM target is the RCM itself: the endoscope direction is undefined there; "
                         "give a point at least a few millimetres away from the RCM")
    q2 = math.asin(max(-1.0, min(1.0, -y / r)))
    q1 = math.atan2(x, -z)
    return q1, q2, r - INSERTION_OFFSET_M, float(roll)


def ecm_ik(pose_rcm: np.ndarray) -> EcmIKResult:
    """Closed-form inverse kinematics of the full EEF pose (position and roll about the view axis).

    The position gives yaw, pitch and insertion (:func:`ecm_ik_position`); the roll is the angle of the
    pose's x axis measured in the (x3, y3) plane of the un-rolled frame 3. The rotation's view axis must
    agree with the position's direction from the RCM (a 4-DoF arm cannot point elsewhere)."""
    pose_rcm = np.asarray(pose_rcm, dtype=np.float64)
    q1, q2, q3, _ = ecm_ik_position(pose_rcm[:3, 3], 0.0)
    frame3 = ecm_fk_rows(q1, q2, q3, 0.0)
    x3 = [frame3[i][0] for i in range(3)]
    y3 = [frame3[i][1] for i in range(3)]
    x4 = pose_rcm[:3, 0]
    q4 = math.atan2(float(np.dot(x4, y3)), float(np.dot(x4, x3)))
    q = np.array([q1, q2, q3, q4])
    return EcmIKResult(q=q, within_limits=within_limits(q))


def euler_xyz(r) -> tuple[float, float, float]:
    """Extrinsic x-y-z Euler angles (PyBullet's convention) of a rotation given as rows (3×3 nested)."""
    pitch = math.asin(max(-1.0, min(1.0, -r[2][0])))
    return math.atan2(r[2][1], r[2][2]), pitch, math.atan2(r[1][0], r[0][0])

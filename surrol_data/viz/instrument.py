"""The PSM instrument drawn from a recorded state: shaft, wrist and the two jaw blades at their recorded opening.

A dataset stores, per arm, the tool-tip position, the tip's rotation angles relative to the tool-down frame and
the jaw angle (the PSM observation layout of :mod:`surrol_data.envs.psm_env`). With the arm's remote centre of
motion known from the task, the env's own closed-form IK (:func:`surrol_data.envs.kinematics.psm_ik`) recovers
the joints, and its forward kinematics the points the drawing needs: the shaft passes through the RCM to the
wrist-pitch axis, the wrist runs to the wrist-yaw axis, and the blades pivot there by ± half the jaw angle.
"""

from __future__ import annotations

import numpy as np

from surrol_data.envs import kinematics as kin

SHAFT_ABOVE_RCM_M = 0.04      # how much of the shaft outside the body (above the RCM) is drawn
BLADE_LENGTH_M = 0.0102       # jaw blade length (the PSM's jaw boxes are 10.2 mm long)
# Observation columns of each PSM arm: (tip position, tip angles, jaw angle). One arm: 0..7; two arms: 0..14.
ARM_COLUMNS = ((slice(0, 3), slice(3, 6), 6), (slice(7, 10), slice(10, 13), 13))


def _euler_to_matrix(angles: np.ndarray) -> np.ndarray:
    """Inverse of :func:`surrol_data.envs.kinematics.euler_xyz`: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = angles
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def instrument_strips(tip_position: np.ndarray, tip_angles: np.ndarray, jaw_angle: float,
                      rcm_position: np.ndarray) -> list[np.ndarray]:
    """Four polylines in world metres: shaft (above the RCM → wrist pitch), wrist (pitch → yaw axis), blade 1,
    blade 2. ``tip_angles`` are the observation's (roll, pitch, yaw) of the tip relative to tool-down."""
    from surrol_data.envs.psm_env import tool_down

    rotation = _euler_to_matrix(np.asarray(tip_angles, np.float64)) @ tool_down(0.0)
    rcm = np.asarray(rcm_position, np.float64)
    tip_in_rcm = kin.pose_from(np.asarray(tip_position, np.float64) - rcm, rotation)
    q = kin.psm_ik(tip_in_rcm).q
    frames = kin.psm_link_frames(q)
    wrist_pitch, wrist_yaw = frames[4][:3, 3] + rcm, frames[5][:3, 3] + rcm
    shaft_dir = (wrist_pitch - rcm) / max(np.linalg.norm(wrist_pitch - rcm), 1e-9)
    x6, y6 = frames[5][:3, 0], frames[5][:3, 1]
    half = 0.5 * float(jaw_angle)
    blades = [np.stack([wrist_yaw, wrist_yaw + BLADE_LENGTH_M * (np.cos(half) * y6 + s * np.sin(half) * x6)])
              for s in (+1.0, -1.0)]
    return [np.stack([rcm - SHAFT_ABOVE_RCM_M * shaft_dir, wrist_pitch]), np.stack([wrist_pitch, wrist_yaw]), *blades]


def episode_instrument_strips(observation: np.ndarray, arm: int, rcm_position: np.ndarray) -> list[list[np.ndarray]]:
    """Per step (T+1), the four polylines of arm ``arm`` from the episode's observations."""
    pos, ang, jaw = ARM_COLUMNS[arm]
    obs = np.asarray(observation, np.float64)
    return [instrument_strips(row[pos], row[ang], row[jaw], rcm_position) for row in obs]


def psm_rcm_positions(env_id: str) -> list[np.ndarray] | None:
    """The remote centres of motion of the task's PSMs (world metres), in arm order; None for ECM tasks or ids
    that are not registered."""
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.envs.bimanual_env import PSM2_RCM
    from surrol_data.envs.psm_env import PSM1_RCM, PsmEnv

    try:
        entry = gym.spec(env_id).entry_point
    except gym.error.Error:
        return None
    module, _, name = str(entry).partition(":")
    cls = getattr(__import__(module, fromlist=[name]), name)
    if not issubclass(cls, PsmEnv):
        return None
    return [PSM1_RCM, PSM2_RCM][: 2 if cls.ACTION_DIM == 10 else 1]

"""Device frames → env actions, as the paper maps the Touch stylus to the tool (action = scale ⊙ Δp).

For each env step k the mapping takes the device reading p(k) and the previous one p(k−1):

* position: the device delta (mm; every device's frame is x right, y up, z towards the user) is permuted and
  signed into the hand frame, multiplied by the motion scale (tool mm per device mm) and expressed in action
  units (1 = 1 cm of tool motion, clipped to [-1, 1]). With ``frame="camera"`` (the default, as on the dVRK)
  the hand frame is the endoscope image's (right, up, away from the viewer): the tool's image moves the way the
  hand moves, and the motion is turned into the arm's action axes with the ``view`` matrix the session passes
  per step (:func:`view_to_action`), so recorded actions keep the robot's frame. ``frame="robot"`` (every
  trace recorded before the camera frame existed) permutes the device axes straight into the action axes;
* rotation: the delta of one gimbal angle × the rotation scale, in action units of ``ACTION_YAW_RAD``;
* jaw: button 1 held lowers the jaw command j by ``jaw_step`` per step down to −1 (the env closes for j < 0);
  released, j rises back to +1 (open);
* clutch: button 2 held zeroes all motion (the jaw command keeps its value), so the operator can re-centre
  the hand; the previous reading still advances, so releasing the clutch never makes the tool jump;
* camera: both buttons held zero the arm's motion and route the motion to the endoscope (ECM) instead.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import numpy as np

from surrol_data.collect.devices.base import BUTTON_CLUTCH, BUTTON_JAW, DeviceFrame
from surrol_data.envs.units import ACTION_POSITION_M, ACTION_YAW_RAD

_MM_PER_ACTION = ACTION_POSITION_M * 1000.0   # 10 mm of tool motion per action unit


FRAMES = ("camera", "robot")
# Per frame, the axis map of a Touch-style device (x right, y up, z towards the user):
#   camera: image right ← x, image up ← y, away from the viewer (deeper) ← −z;
#   robot:  action x ← z, action y ← x, action z ← y (SurRoL-v2's map: the reference's world axes).
FRAME_AXES = {"camera": ((0, 1, 2), (1.0, 1.0, -1.0)), "robot": ((2, 0, 1), (1.0, 1.0, 1.0))}


@dataclass(frozen=True)
class MappingSettings:
    frame: str = "camera"                           # the hand frame: FRAMES (see the module docstring)
    motion_scale: float = 0.5                       # tool mm per device mm
    rotation_scale: float = 0.5                     # tool rad per device gimbal rad
    axis_permutation: tuple[int, int, int] = FRAME_AXES["camera"][0]   # hand axis i ← device axis axis_permutation[i]
    axis_sign: tuple[float, float, float] = FRAME_AXES["camera"][1]
    rotation_axis: int = 2                          # the gimbal angle that drives yaw/pitch (or ECM roll)
    rotation_sign: float = -1.0
    jaw_step: float = 0.5                           # jaw command change per step while button 1 is held/released
    camera_motion_scale: float = 0.2                # endoscope mm per device mm in camera mode

    def as_dict(self) -> dict:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), sort_keys=True)

    def __post_init__(self):
        if self.frame not in FRAMES:
            raise ValueError(f"mapping frame must be one of {', '.join(FRAMES)}, got {self.frame!r}")

    def tool_delta_mm(self, device_delta_mm: np.ndarray, view: np.ndarray | None = None) -> np.ndarray:
        """Device-frame delta (mm) → direction along the action's axes (mm of device motion, before scaling).
        ``view``: the camera frame's (right, up, away) → action axes matrix (:func:`view_to_action`)."""
        d = np.asarray(device_delta_mm, dtype=np.float64)
        hand = d[list(self.axis_permutation)] * np.asarray(self.axis_sign)
        return hand if self.frame == "robot" else self._view(view) @ hand

    def device_delta_mm(self, tool_delta_mm: np.ndarray, view: np.ndarray | None = None) -> np.ndarray:
        """Inverse of :meth:`tool_delta_mm` followed by the motion scale: the hand motion (device frame, mm)
        that moves the tool by ``tool_delta_mm``. A simulated operator's internal model of the mapping."""
        t = np.asarray(tool_delta_mm, dtype=np.float64) / self.motion_scale
        if self.frame == "camera":
            t = self._view(view).T @ t     # the view matrix is a rotation: its inverse is its transpose
        d = np.zeros(3)
        d[list(self.axis_permutation)] = t * np.asarray(self.axis_sign)
        return d

    def _view(self, view) -> np.ndarray:
        if view is None:
            raise ValueError("a camera-frame mapping needs the view (view_to_action(env, arm)) to turn the hand's "
                             "motion into the arm's action axes")
        return np.asarray(view, dtype=np.float64)


def frame_defaults(frame: str) -> dict:
    """The axis map that makes ``frame`` natural for a device whose frame is x right, y up, z towards the user."""
    if frame not in FRAMES:
        raise ValueError(f"mapping frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    permutation, sign = FRAME_AXES[frame]
    return {"frame": frame, "axis_permutation": permutation, "axis_sign": sign}


def view_to_action(env, arm: int = 0) -> np.ndarray:
    """The 3×3 matrix that turns a motion along the endoscope image's (right, up, away from the viewer) axes into
    arm ``arm``'s action axes, for ``env`` (unwrapped) as it is now; zeros when the action moves no position
    (MisOrient's roll).

    The image axes are :func:`surrol_data.envs.camera.camera_axes` of the endoscope the operator watches
    (``env.endoscope_pose()``); the action axes are ``env.action_axes(...)`` (world for PSMs, the RCM frame for
    ECMReach, the tracking frame for StaticTrack/ActiveTrack)."""
    from surrol_data.envs.camera import camera_axes

    env = getattr(env, "unwrapped", env)
    action = env.action_axes(arm) if arm else env.action_axes()
    if action is None:
        return np.zeros((3, 3))
    axes = camera_axes(env.endoscope_pose())
    image = np.column_stack([axes.right, [-v for v in axes.down], axes.forward])
    return np.asarray(action, dtype=np.float64).T @ image


@dataclass
class MappedStep:
    """What one device reading asks for."""
    arm: np.ndarray                  # (5,) PSM action: dx, dy, dz, drot, jaw
    camera: np.ndarray               # (4,) ECM action in camera mode: dx, dy, dz, droll (zeros otherwise)
    clutch: bool                     # button 2 held (alone)
    jaw_button: bool                 # button 1 held
    camera_mode: bool                # both buttons held
    raw: DeviceFrame | None = field(default=None, repr=False)


class ActionMapper:
    """Stateful mapping for one device: remembers p(k−1) and the jaw ramp. Call :meth:`reset` per episode."""

    def __init__(self, settings: MappingSettings | None = None, jaw_open: float = 1.0):
        self.settings = settings or MappingSettings()
        self.jaw_open = jaw_open
        self.reset()

    def reset(self) -> None:
        self._prev: DeviceFrame | None = None
        self.jaw = self.jaw_open

    def __call__(self, frame: DeviceFrame, view: np.ndarray | None = None) -> MappedStep:
        """``view``: :func:`view_to_action` of the arm this device drives (needed by camera-frame mappings)."""
        s = self.settings
        prev = self._prev if self._prev is not None else frame   # first reading of an episode: no motion
        self._prev = frame
        jaw_button = bool(frame.buttons & BUTTON_JAW)
        clutch_button = bool(frame.buttons & BUTTON_CLUTCH)
        camera_mode = jaw_button and clutch_button
        clutch = clutch_button and not camera_mode

        tool = s.tool_delta_mm(frame.position_mm - prev.position_mm, view)
        rot = float(frame.gimbal_rad[s.rotation_axis] - prev.gimbal_rad[s.rotation_axis]) * s.rotation_sign
        arm = np.zeros(5)
        camera = np.zeros(4)
        if camera_mode:
            camera[:3] = tool * s.camera_motion_scale / _MM_PER_ACTION
            camera[3] = rot * s.rotation_scale / ACTION_YAW_RAD
        elif not clutch:
            arm[:3] = tool * s.motion_scale / _MM_PER_ACTION
            arm[3] = rot * s.rotation_scale / ACTION_YAW_RAD
            # The jaw ramps only on a plain button-1 press; under the clutch or in camera mode it holds.
            if jaw_button:
                self.jaw = max(self.jaw - s.jaw_step, -1.0)
            else:
                self.jaw = min(self.jaw + s.jaw_step, self.jaw_open)
        arm[4] = self.jaw
        return MappedStep(arm=np.clip(arm, -1.0, 1.0).astype(np.float32),
                          camera=np.clip(camera, -1.0, 1.0).astype(np.float32),
                          clutch=clutch, jaw_button=jaw_button, camera_mode=camera_mode, raw=frame)

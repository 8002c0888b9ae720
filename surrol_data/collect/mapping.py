"""Device frames → env actions, as the paper maps the Touch stylus to the tool (action = scale ⊙ Δp).

For each env step k the mapping takes the device reading p(k) and the previous one p(k−1):

* position: the device delta (mm) is permuted and signed into the tool frame, multiplied by the motion
  scale (tool mm per device mm) and expressed in action units (1 = 1 cm of tool motion, clipped to [-1, 1]);
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


@dataclass(frozen=True)
class MappingSettings:
    motion_scale: float = 0.5                       # tool mm per device mm
    rotation_scale: float = 0.5                     # tool rad per device gimbal rad
    axis_permutation: tuple[int, int, int] = (2, 0, 1)   # tool axis i ← device axis axis_permutation[i]
    axis_sign: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rotation_axis: int = 2                          # the gimbal angle that drives yaw/pitch (or ECM roll)
    rotation_sign: float = -1.0
    jaw_step: float = 0.5                           # jaw command change per step while button 1 is held/released
    camera_motion_scale: float = 0.2                # endoscope mm per device mm in camera mode

    def as_dict(self) -> dict:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), sort_keys=True)

    def tool_delta_mm(self, device_delta_mm: np.ndarray) -> np.ndarray:
        """Device-frame delta (mm) → tool-frame direction (mm of device motion, before scaling)."""
        d = np.asarray(device_delta_mm, dtype=np.float64)
        return d[list(self.axis_permutation)] * np.asarray(self.axis_sign)

    def device_delta_mm(self, tool_delta_mm: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`tool_delta_mm` followed by the motion scale: the hand motion (device frame, mm)
        that moves the tool by ``tool_delta_mm``. A simulated operator's internal model of the mapping."""
        t = np.asarray(tool_delta_mm, dtype=np.float64) / self.motion_scale * np.asarray(self.axis_sign)
        d = np.zeros(3)
        d[list(self.axis_permutation)] = t
        return d


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

    def __call__(self, frame: DeviceFrame) -> MappedStep:
        s = self.settings
        prev = self._prev if self._prev is not None else frame   # first reading of an episode: no motion
        self._prev = frame
        jaw_button = bool(frame.buttons & BUTTON_JAW)
        clutch_button = bool(frame.buttons & BUTTON_CLUTCH)
        camera_mode = jaw_button and clutch_button
        clutch = clutch_button and not camera_mode

        tool = s.tool_delta_mm(frame.position_mm - prev.position_mm)
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

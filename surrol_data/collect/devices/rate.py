"""A virtual stylus for rate devices (keyboard, gamepad, SpaceMouse).

Those devices report a velocity (a held key, a stick deflection, a puck push), not a position. To go
through the same mapping as a Touch stylus they integrate that velocity into an absolute position (mm)
and gimbal angle (rad); the mapping then takes consecutive differences again, so a held input moves the
tool at a constant speed. The integration step is one control period per :meth:`read`, not wall-clock
time: the session reads once per env step, and a fixed step keeps replays and tests exact.
"""

from __future__ import annotations

import time

import numpy as np

from surrol_data.collect.devices.base import DeviceFrame
from surrol_data.envs.units import CONTROL_PERIOD_S

# A full deflection moves the virtual stylus 40 mm/s: 8 mm per step, i.e. 4 mm of tool motion at the default
# motion scale 0.5 — the scripted oracle's speed (0.4 cm per step), slow enough to aim at a needle.
DEFAULT_SPEED_MM_S = 40.0
DEFAULT_TURN_RAD_S = np.deg2rad(60.0)


class VirtualStylus:
    """Integrates (velocity in [-1, 1]^3, turn rate in [-1, 1]) into an absolute stylus pose."""

    def __init__(self, speed_mm_s: float = DEFAULT_SPEED_MM_S, turn_rad_s: float = DEFAULT_TURN_RAD_S,
                 rotation_axis: int = 2, step_s: float = CONTROL_PERIOD_S):
        if speed_mm_s <= 0 or turn_rad_s <= 0 or step_s <= 0:
            raise ValueError(f"virtual stylus: speed ({speed_mm_s} mm/s), turn rate ({turn_rad_s} rad/s) and "
                             f"step ({step_s} s) must be positive")
        self.speed_mm_s, self.turn_rad_s, self.step_s = float(speed_mm_s), float(turn_rad_s), float(step_s)
        self.rotation_axis = int(rotation_axis)
        self.position_mm = np.zeros(3)
        self.gimbal_rad = np.zeros(3)

    def advance(self, velocity, turn: float, buttons: int) -> DeviceFrame:
        v = np.clip(np.asarray(velocity, dtype=np.float64), -1.0, 1.0)
        self.position_mm = self.position_mm + v * self.speed_mm_s * self.step_s
        self.gimbal_rad = self.gimbal_rad.copy()
        self.gimbal_rad[self.rotation_axis] += float(np.clip(turn, -1.0, 1.0)) * self.turn_rad_s * self.step_s
        return DeviceFrame(self.position_mm.copy(), self.gimbal_rad.copy(), int(buttons), time.monotonic())

    def settings(self) -> dict:
        return {"speed_mm_s": self.speed_mm_s, "turn_rad_s": self.turn_rad_s, "step_s": self.step_s,
                "rotation_axis": self.rotation_axis}

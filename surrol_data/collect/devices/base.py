"""The teleoperation device interface: every input device, real or simulated, yields :class:`DeviceFrame`s.

A frame is an absolute reading (stylus position in millimetres, gimbal angles in radians, a button
bitmask, a timestamp); the mapping in :mod:`surrol_data.collect.mapping` turns consecutive frames into env
actions. Rate devices (keyboard, gamepad, SpaceMouse) integrate their input into a virtual stylus position
so that every device goes through the same mapping.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

BUTTON_JAW = 1      # button 1 held: the jaw ramps closed; released: it ramps open
BUTTON_CLUTCH = 2   # button 2 held: motion is zeroed (clutch); both held: the device drives the camera (ECM)
# The takeover control of an intervention session (``collect --source intervene``): held, the operator drives the
# arm and the policy's action is only recorded; released, the policy drives. The mapping ignores it.
BUTTON_TAKEOVER = 4


class DeviceError(RuntimeError):
    """A device could not be found, opened or read; the message says what to install or check."""


@dataclass(frozen=True)
class DeviceFrame:
    position_mm: np.ndarray   # (3,) stylus position in the device's own frame, millimetres
    gimbal_rad: np.ndarray    # (3,) gimbal angles, radians
    buttons: int              # bitmask of BUTTON_JAW | BUTTON_CLUTCH | BUTTON_TAKEOVER
    t: float                  # seconds on the device's clock

    def to_row(self) -> list[float]:
        """Flat row for device traces: x, y, z (mm), g0, g1, g2 (rad), buttons, t."""
        return [*map(float, self.position_mm), *map(float, self.gimbal_rad), float(self.buttons), float(self.t)]

    @classmethod
    def from_row(cls, row) -> "DeviceFrame":
        row = np.asarray(row, dtype=np.float64)
        return cls(row[0:3].copy(), row[3:6].copy(), int(row[6]), float(row[7]))


class Device(ABC):
    """connect → read … read → disconnect (also a context manager).

    ``name`` is the provenance device name (``touch``, ``keyboard``, ``gamepad``, ``spacemouse``, ``replay``,
    ``simulated-operator``). ``observe`` is called by the session with every env observation before the next
    ``read``; only devices that watch the scene (the simulated operator) use it.
    """

    name: str = "device"

    @abstractmethod
    def connect(self) -> None: ...

    @abstractmethod
    def read(self) -> DeviceFrame: ...

    @abstractmethod
    def disconnect(self) -> None: ...

    def observe(self, obs: dict, info: dict) -> None:  # noqa: B027 (optional hook)
        pass

    def settings(self) -> dict:
        """Device parameters worth recording in provenance (JSON-serialisable)."""
        return {}

    def __enter__(self) -> "Device":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.disconnect()

"""The ``spacemouse`` device: a 3Dconnexion SpaceMouse through hidapi (the ``hid`` package), as a virtual stylus.

The puck reports HID input reports (little-endian int16 values, about ±350 at full deflection):

* report 1: translation x, y, z (7 bytes); newer models (SpaceMouse Compact / Wireless) send translation
  *and* rotation rx, ry, rz in one 13-byte report 1;
* report 2: rotation rx, ry, rz (older models);
* report 3: buttons bitmask (bit 0 left button, bit 1 right button).

Each :meth:`SpaceMouseDevice.read` drains the pending reports without blocking and integrates the latest
deflection; the left button is the jaw (button 1), the right one the clutch (button 2), the puck's twist
(rz) the yaw.
"""

from __future__ import annotations

import numpy as np

from surrol_data.collect.devices.base import BUTTON_CLUTCH, BUTTON_JAW, Device, DeviceError, DeviceFrame
from surrol_data.collect.devices.rate import DEFAULT_SPEED_MM_S, DEFAULT_TURN_RAD_S, VirtualStylus

VENDOR_IDS = (0x046D, 0x256F)   # Logitech (older 3Dconnexion models), 3Dconnexion
LOGITECH_SPACE_PIDS = range(0xC600, 0xC700)   # Logitech's other products (mice, receivers) are not pucks
FULL_SCALE = 350.0
REPORT_SIZE = 13


def parse_report(report, state: dict) -> dict:
    """Update ``state`` (translation (3,), rotation (3,), buttons) from one HID input report (bytes or ints)."""
    data = bytes(report)
    if not data:
        return state
    kind = data[0]

    def int16s(payload: bytes, n: int) -> np.ndarray:
        return np.frombuffer(payload[: 2 * n], dtype="<i2").astype(np.float64) / FULL_SCALE

    if kind == 1 and len(data) >= 13:
        values = int16s(data[1:13], 6)
        state["translation"], state["rotation"] = values[:3], values[3:]
    elif kind == 1 and len(data) >= 7:
        state["translation"] = int16s(data[1:7], 3)
    elif kind == 2 and len(data) >= 7:
        state["rotation"] = int16s(data[1:7], 3)
    elif kind == 3 and len(data) >= 2:
        state["buttons"] = int.from_bytes(data[1:], "little")
    return state


class SpaceMouseDevice(Device):
    """The first 3Dconnexion device found (or ``path``). ``hid_device`` injects an object with hidapi's methods."""

    name = "spacemouse"
    realtime = True

    def __init__(self, path: bytes | None = None, speed_mm_s: float = DEFAULT_SPEED_MM_S,
                 turn_rad_s: float = DEFAULT_TURN_RAD_S, rotation_axis: int = 2, deadzone: float = 0.05,
                 hid_device=None):
        self.path = path
        self.deadzone = float(deadzone)
        self.stylus = VirtualStylus(speed_mm_s, turn_rad_s, rotation_axis)
        self._dev = hid_device
        self._injected = hid_device is not None
        self._product = ""
        self._state = {"translation": np.zeros(3), "rotation": np.zeros(3), "buttons": 0}

    def connect(self) -> None:
        if self._dev is not None and self._injected:
            return
        from surrol_data.extras import MissingExtra, require

        try:
            hid = require("hid")
        except MissingExtra as e:
            raise DeviceError(f"the spacemouse device: {e}") from None
        path = self.path
        if path is None:
            found = [d for vid in VENDOR_IDS for d in hid.enumerate(vid, 0)
                     if d["vendor_id"] != 0x046D or d["product_id"] in LOGITECH_SPACE_PIDS]
            if not found:
                raise DeviceError("no 3Dconnexion SpaceMouse found (vendor ids 046d/256f): plug it in and allow "
                                  "access to its /dev/hidraw* node (a udev rule with MODE=\"0666\" for those vendors)")
            path, self._product = found[0]["path"], found[0].get("product_string") or ""
        dev = hid.device()
        try:
            dev.open_path(path)
        except OSError as e:
            raise DeviceError(f"cannot open the SpaceMouse at {path!r} ({e}): check the permissions of its "
                              "/dev/hidraw* node") from None
        dev.set_nonblocking(1)
        self._dev = dev

    def read(self) -> DeviceFrame:
        if self._dev is None:
            raise DeviceError("spacemouse read before connect()")
        while True:
            try:
                report = self._dev.read(REPORT_SIZE)
            except (OSError, ValueError) as e:
                raise DeviceError(f"the SpaceMouse stopped answering ({e}): it was unplugged or lost power") from None
            if not report:
                break
            parse_report(report, self._state)
        t = np.where(np.abs(self._state["translation"]) < self.deadzone, 0.0, self._state["translation"])
        # HID axes: x right, y towards the user, z down; the virtual stylus uses x right, y up, z towards the user
        velocity = np.array([t[0], -t[2], t[1]])
        twist = float(self._state["rotation"][2])
        turn = 0.0 if abs(twist) < self.deadzone else -twist
        b = int(self._state["buttons"])
        buttons = (BUTTON_JAW if b & 1 else 0) | (BUTTON_CLUTCH if b & 2 else 0)
        return self.stylus.advance(velocity, turn, buttons)

    def disconnect(self) -> None:
        if self._dev is not None and not self._injected:
            self._dev.close()
            self._dev = None

    def settings(self) -> dict:
        return {"product": self._product, "deadzone": self.deadzone, "full_scale": FULL_SCALE,
                **self.stylus.settings()}

"""The ``gamepad`` device: a game controller through pygame's joystick module, as a virtual stylus.

Default layout (SDL's mapping of Xbox-style pads), in the device frame every device shares (x right, y up,
z towards the user): left stick left/right → x, left stick pushed forward → −z (away from you: the tool goes
deeper into the image under the default camera-frame mapping), right stick up/down → y, shoulder buttons → yaw, button A → jaw (button 1), button B → clutch
(button 2). Sticks are dead-zoned (centred sticks drift by a few percent) and integrated by
:class:`~surrol_data.collect.devices.rate.VirtualStylus`. A pad unplugged mid-session raises DeviceError.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass

import numpy as np

from surrol_data.collect.devices.base import (BUTTON_CLUTCH, BUTTON_JAW, BUTTON_TAKEOVER, Device, DeviceError,
                                              DeviceFrame)
from surrol_data.collect.devices.rate import DEFAULT_SPEED_MM_S, DEFAULT_TURN_RAD_S, VirtualStylus


@dataclass(frozen=True)
class PadLayout:
    # (axis index, sign) per device axis x, y, z. SDL reports a stick pushed up/forward as −1: the right stick's
    # up is +y, the left stick's forward is −z (away from the user, as a stylus pushed away).
    axes: tuple[tuple[int, float], tuple[int, float], tuple[int, float]] = ((0, 1.0), (3, -1.0), (1, 1.0))
    turn_left: int = 4      # left shoulder
    turn_right: int = 5     # right shoulder
    jaw: int = 0            # A
    clutch: int = 1         # B
    deadzone: float = 0.15
    takeover_axis: int = 5  # right trigger (an axis from -1 released to 1 pressed): held, the operator takes over


class GamepadDevice(Device):
    """Joystick ``index`` (0 = first pad). ``joystick`` injects an object with pygame's Joystick methods."""

    name = "gamepad"
    realtime = True

    def __init__(self, index: int = 0, layout: PadLayout | None = None, speed_mm_s: float = DEFAULT_SPEED_MM_S,
                 turn_rad_s: float = DEFAULT_TURN_RAD_S, rotation_axis: int = 2, joystick=None):
        self.index = int(index)
        self.layout = layout or PadLayout()
        self.stylus = VirtualStylus(speed_mm_s, turn_rad_s, rotation_axis)
        self._joystick = joystick
        self._injected = joystick is not None
        self._pygame = None

    def connect(self) -> None:
        # The dummy video driver lets pygame's event queue run without a window (headless sessions).
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        from surrol_data.extras import MissingExtra, require

        try:
            pygame = require("pygame")
        except MissingExtra as e:
            raise DeviceError(f"the gamepad device: {e}") from None
        self._pygame = pygame
        pygame.display.init()   # the event queue (device added/removed) lives in the video subsystem
        pygame.joystick.init()
        if self._joystick is None:
            count = pygame.joystick.get_count()
            if self.index >= count:
                raise DeviceError(f"gamepad {self.index} not found ({count} connected): plug in a game controller "
                                  "(check it shows up with `ls /dev/input/js*`), or pick another with --side/index")
            self._joystick = pygame.joystick.Joystick(self.index)
        self._check_layout()

    def _check_layout(self) -> None:
        js, lay = self._joystick, self.layout
        n_axes, n_buttons = js.get_numaxes(), js.get_numbuttons()
        need_axes = max(a for a, _ in lay.axes) + 1
        need_buttons = max(lay.turn_left, lay.turn_right, lay.jaw, lay.clutch) + 1
        if n_axes < need_axes or n_buttons < need_buttons:
            raise DeviceError(f"gamepad {js.get_name()!r} has {n_axes} axes and {n_buttons} buttons; the layout "
                              f"needs {need_axes} and {need_buttons}: pass a PadLayout that fits this controller")

    def read(self) -> DeviceFrame:
        if self._joystick is None:
            raise DeviceError("gamepad read before connect()")
        pg = self._pygame
        for event in pg.event.get([pg.JOYDEVICEREMOVED, pg.JOYDEVICEADDED]):
            if event.type == pg.JOYDEVICEREMOVED and self._removed(event):
                raise DeviceError(f"gamepad {self._joystick.get_name()!r} was unplugged")
        pg.event.pump()
        return self._frame()

    def _frame(self) -> DeviceFrame:
        """The stylus after one step of the pad as it reads now (sticks, shoulders, A, B, the trigger)."""
        js, lay = self._joystick, self.layout
        velocity = np.array([sign * self._deadzoned(js.get_axis(axis)) for axis, sign in lay.axes])
        turn = float(js.get_button(lay.turn_left)) - float(js.get_button(lay.turn_right))
        buttons = (BUTTON_JAW if js.get_button(lay.jaw) else 0) | (BUTTON_CLUTCH if js.get_button(lay.clutch) else 0)
        # (A pad without the trigger axis has no takeover control: its layout check does not ask for one.)
        # Half pulled: SDL reads 0 before a trigger's first pull, so "above 0" would read an untouched one as held.
        if lay.takeover_axis < js.get_numaxes() and js.get_axis(lay.takeover_axis) > 0.5:
            buttons |= BUTTON_TAKEOVER
        return self.stylus.advance(velocity, turn, buttons)

    def _removed(self, event) -> bool:
        instance = getattr(event, "instance_id", None)
        try:
            ours = self._joystick.get_instance_id()
        except (AttributeError, Exception):   # an injected or already-closed joystick
            ours = None
        return instance is None or ours is None or instance == ours

    def _deadzoned(self, value: float) -> float:
        dz = self.layout.deadzone
        v = float(value)
        return 0.0 if abs(v) < dz else np.sign(v) * (abs(v) - dz) / (1.0 - dz)

    def disconnect(self) -> None:
        if self._joystick is not None and not self._injected:
            try:
                self._joystick.quit()
            except Exception:   # pygame raises if the pad is already gone; nothing left to release
                pass
            self._joystick = None

    def settings(self) -> dict:
        name = self._joystick.get_name() if self._joystick is not None else ""
        return {"index": self.index, "controller": name, "layout": asdict(self.layout), **self.stylus.settings()}

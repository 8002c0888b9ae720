"""The ``keyboard`` device: keys held → a virtual stylus, from a terminal or from the PyBullet GUI window.

Two key sources feed the same key-state logic (:class:`KeyTracker`):

* :class:`TerminalKeys` reads raw stdin (cbreak mode, no extra package). A terminal sends no key-up events,
  only the first press and the auto-repeats, so a key counts as held until ``hold_s`` after its last
  character (longer than the usual 250–600 ms auto-repeat delay, shorter than a deliberate pause);
* :class:`PyBulletKeys` reads ``getKeyboardEvents`` of the GUI window, which reports real downs and ups.

Layouts (SurRoL-v2's keys; directions on the endoscope image under the default camera-frame
:class:`~surrol_data.collect.mapping.MappingSettings`): left hand ``w/s`` up/down, ``d/a`` right/left, ``e/q``
deeper (away from you)/back towards you, ``z/x`` ±yaw, ``c`` jaw (button 1), ``v`` clutch (button 2), ``t`` takeover
(intervention sessions); right hand ``i/k``, ``l/j``, ``o/u``, ``m/,``, jaw ``n``, clutch ``b``, takeover ``y``. The
keys move the virtual stylus along the device axes (x right, y up, z towards the user) as a hand would move a stylus.
Session keys (read by the haptic session from the same tracker): ``r`` redo the attempt, ``f`` discard it, ``Esc``
end the session; in an intervention session ``space`` held takes every arm over.
"""

from __future__ import annotations

import os
import select
import sys
import termios
import time
import tty
from dataclasses import dataclass

import numpy as np

from surrol_data.collect.devices.base import (BUTTON_CLUTCH, BUTTON_JAW, BUTTON_TAKEOVER, Device, DeviceError,
                                              DeviceFrame)
from surrol_data.collect.devices.rate import DEFAULT_SPEED_MM_S, DEFAULT_TURN_RAD_S, VirtualStylus


@dataclass(frozen=True)
class KeyLayout:
    motion: dict[str, tuple[int, float]]   # key -> (device axis, direction)
    turn: dict[str, float]                 # key -> yaw direction
    jaw: str
    clutch: str
    takeover: str

    def keys(self) -> set[str]:
        return {*self.motion, *self.turn, self.jaw, self.clutch, self.takeover}


# Device axes: x right, y up, z towards the user (q / u pull the stylus towards you).
LAYOUTS = {
    "left": KeyLayout(motion={"w": (1, 1.0), "s": (1, -1.0), "d": (0, 1.0), "a": (0, -1.0),
                              "q": (2, 1.0), "e": (2, -1.0)},
                      turn={"z": 1.0, "x": -1.0}, jaw="c", clutch="v", takeover="t"),
    "right": KeyLayout(motion={"i": (1, 1.0), "k": (1, -1.0), "l": (0, 1.0), "j": (0, -1.0),
                               "u": (2, 1.0), "o": (2, -1.0)},
                       turn={"m": 1.0, ",": -1.0}, jaw="n", clutch="b", takeover="y"),
}
REDO_KEY, DISCARD_KEY, QUIT_KEY, SAVE_KEY = "r", "f", "esc", "enter"
TAKEOVER_KEY = " "   # held in an intervention session: the operator drives every arm (a Touch has no third button)
SESSION_KEYS = (REDO_KEY, DISCARD_KEY, QUIT_KEY, SAVE_KEY)
_ESCAPES = {"\x1b[A": "up", "\x1b[B": "down", "\x1b[C": "right", "\x1b[D": "left"}


@dataclass(frozen=True)
class KeyEvent:
    key: str
    down: bool | None   # True / False: a real press / release; None: a character (press or auto-repeat)


class TerminalKeys:
    """Characters typed in a terminal (``fd``, default stdin), read without blocking in cbreak mode.

    cbreak keeps Ctrl-C as SIGINT, so the recorder's handler still ends the session cleanly.
    """

    def __init__(self, fd: int | None = None):
        self.fd = sys.stdin.fileno() if fd is None else fd
        self._saved = None

    def start(self) -> None:
        if not os.isatty(self.fd):
            raise DeviceError("the keyboard device needs a terminal (stdin is not one) or the PyBullet GUI "
                              "window: run the session in a terminal, or with --gui on a machine with a display")
        self._saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd)

    def stop(self) -> None:
        if self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None

    def poll(self) -> list[KeyEvent]:
        data = b""
        while select.select([self.fd], [], [], 0)[0]:
            chunk = os.read(self.fd, 1024)
            if not chunk:
                break
            data += chunk
        return [KeyEvent(k, None) for k in _split_keys(data.decode(errors="ignore"))]


def _split_keys(text: str) -> list[str]:
    keys, i = [], 0
    while i < len(text):
        seq = text[i:i + 3]
        if seq in _ESCAPES:
            keys.append(_ESCAPES[seq])
            i += 3
        elif text[i] == "\x1b":
            keys.append("esc")
            i += 1
        elif text[i] in "\r\n":
            keys.append("enter")
            i += 1
        else:
            keys.append(text[i].lower())
            i += 1
    return keys


class PyBulletKeys:
    """Keys of the PyBullet GUI window (``client.getKeyboardEvents``: key code -> state bits)."""

    KEY_IS_DOWN, KEY_WAS_TRIGGERED, KEY_WAS_RELEASED = 1, 2, 4   # pybullet's state bits
    _SPECIAL = {27: "esc", 65309: "enter"}   # 65309: pybullet's B3G_RETURN

    def __init__(self, client):
        self.client = client
        self._down: set[str] = set()

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def poll(self) -> list[KeyEvent]:
        events = []
        for code, state in self.client.getKeyboardEvents().items():
            name = self._SPECIAL.get(code) or (chr(code).lower() if 32 <= code < 127 else None)
            if name is None:
                continue
            if state & self.KEY_WAS_TRIGGERED:
                events.append(KeyEvent(name, True))
            if state & self.KEY_WAS_RELEASED:
                events.append(KeyEvent(name, False))
            elif state & self.KEY_IS_DOWN and not state & self.KEY_WAS_TRIGGERED:
                events.append(KeyEvent(name, True))   # still held: keeps the key down
        # Every call lists the keys that are down; one that is no longer listed was released (focus lost, ...).
        now_down = {e.key for e in events if e.down}
        events += [KeyEvent(k, False) for k in sorted(self._down - now_down - {e.key for e in events})]
        self._down = now_down
        return events


class KeyTracker:
    """Held keys and fresh presses from one key source; shared by keyboard devices and the session."""

    def __init__(self, source, hold_s: float = 0.6, clock=time.monotonic):
        self.source = source
        self.hold_s = float(hold_s)
        self.clock = clock
        self._down: dict[str, float | None] = {}   # key -> time of last character (None: held until released)
        self._pressed: list[str] = []
        self._started = False

    def start(self) -> None:
        if not self._started:
            self.source.start()
            self._started = True

    def stop(self) -> None:
        if self._started:
            self.source.stop()
            self._started = False

    def update(self) -> None:
        now = self.clock()
        for ev in self.source.poll():
            fresh = ev.key not in self.held()
            if ev.down is False:
                self._down.pop(ev.key, None)
                continue
            self._down[ev.key] = now if ev.down is None else None
            if fresh:
                self._pressed.append(ev.key)

    def held(self) -> set[str]:
        now = self.clock()
        return {k for k, t in self._down.items() if t is None or now - t <= self.hold_s}

    def pop_pressed(self) -> list[str]:
        """Keys pressed since the last call (each press once, auto-repeats not counted)."""
        pressed, self._pressed = self._pressed, []
        return pressed


class KeyboardDevice(Device):
    """One arm from one hand's keys; two devices with the ``left`` and ``right`` layouts drive two arms."""

    name = "keyboard"
    realtime = True

    def __init__(self, tracker: KeyTracker, layout: str = "left", speed_mm_s: float = DEFAULT_SPEED_MM_S,
                 turn_rad_s: float = DEFAULT_TURN_RAD_S, rotation_axis: int = 2):
        if layout not in LAYOUTS:
            raise ValueError(f"keyboard: layout must be one of {sorted(LAYOUTS)}, got {layout!r}")
        self.tracker = tracker
        self.layout_name = layout
        self.layout = LAYOUTS[layout]
        self.stylus = VirtualStylus(speed_mm_s, turn_rad_s, rotation_axis)

    def connect(self) -> None:
        self.tracker.start()

    def disconnect(self) -> None:
        self.tracker.stop()

    def read(self) -> DeviceFrame:
        self.tracker.update()
        held = self.tracker.held()
        lay = self.layout
        velocity = np.zeros(3)
        for key, (axis, sign) in lay.motion.items():
            if key in held:
                velocity[axis] += sign
        turn = sum(sign for key, sign in lay.turn.items() if key in held)
        buttons = ((BUTTON_JAW if lay.jaw in held else 0) | (BUTTON_CLUTCH if lay.clutch in held else 0)
                   | (BUTTON_TAKEOVER if lay.takeover in held else 0))
        return self.stylus.advance(velocity, turn, buttons)

    def settings(self) -> dict:
        return {"layout": self.layout_name, "source": type(self.tracker.source).__name__,
                "hold_s": self.tracker.hold_s, **self.stylus.settings()}

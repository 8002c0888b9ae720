"""Devices driven from a web browser (the web console): the page's keys or its gamepad.

The page sends its input state (the keys held, or the Gamepad API's standard-mapping axes and buttons) with a
sequence number; the process that runs the operator's env hands each message to :class:`BrowserInput`. The devices
read the latest state once per env step, as the keyboard and gamepad devices read theirs, and go through the same
virtual stylus and the same mapping (the camera frame by default): ``browser-keyboard`` is the ``keyboard`` device's
key logic (:class:`~surrol_data.collect.devices.keyboard.KeyTracker`, the same layouts) fed with the page's real
key downs and ups; ``browser-gamepad`` is the ``gamepad`` device's (the same :class:`PadLayout`: the Gamepad API's
standard mapping numbers the sticks and buttons as SDL's Xbox mapping that layout was written for). Their settings,
recorded in each episode's provenance, add the browser's input rate and the input-to-frame latency the page
measured during the episode.
"""

from __future__ import annotations

import time

import numpy as np

from surrol_data.collect.devices.gamepad import GamepadDevice, PadLayout
from surrol_data.collect.devices.keyboard import LAYOUTS, SESSION_KEYS, KeyboardDevice, KeyEvent, KeyTracker

# What a page may send (anything else is dropped): the motion keys of both hands, and the standard mapping's axes
# (two sticks) and buttons (17: face, shoulders, triggers, select/start, stick presses, d-pad, home).
KEYS = frozenset(k for layout in LAYOUTS.values() for k in layout.keys())
PAD_AXES, PAD_BUTTONS = 4, 17
LATENCY_SAMPLES = 20_000   # per episode at most (an hour of 5 frames/s)


class BrowserInput:
    """The latest input state of one page, and what it says about the page's input rate and latency.

    ``pump``: called before every read to take in the messages that arrived (the worker's connection)."""

    def __init__(self, pump=None, clock=time.monotonic):
        self.pump = pump or (lambda: None)
        self.clock = clock
        self.keys: frozenset[str] = frozenset()
        self.axes = np.zeros(PAD_AXES)
        self.buttons = np.zeros(PAD_BUTTONS)
        self.pad_name = ""
        self.seq = -1               # the sequence number of the state the devices read last
        self.presses: list[str] = []   # session keys pressed (the page's buttons and keys), not yet polled
        self.start_episode()

    def start_episode(self) -> None:
        """Start counting the input rate and latency anew (at each attempt's first step)."""
        self._since = self.clock()
        self._messages = 0
        self._latency_ms: list[float] = []

    def apply(self, message: dict) -> None:
        """One input message of the page: ``seq`` and ``keys`` (names) or ``axes`` / ``buttons`` (numbers)."""
        self._messages += 1
        self.seq = max(self.seq, int(message.get("seq", self.seq)))
        if "keys" in message:
            self.keys = frozenset(k for k in message["keys"] if k in KEYS)
        if "axes" in message:
            self.axes = _bounded(message["axes"], PAD_AXES, -1.0)
        if "buttons" in message:
            self.buttons = _bounded(message["buttons"], PAD_BUTTONS, 0.0)
        if "pad" in message:
            self.pad_name = str(message["pad"])[:80]

    def press(self, key: str) -> None:
        """A session key (:data:`SESSION_KEYS`) pressed on the page."""
        if key in SESSION_KEYS:
            self.presses.append(key)

    def add_latency(self, samples_ms) -> None:
        """Input-to-frame latencies the page measured (ms): from sending an input to showing the first frame
        stepped with it."""
        room = LATENCY_SAMPLES - len(self._latency_ms)
        self._latency_ms += [float(v) for v in list(samples_ms)[:max(room, 0)] if 0 <= float(v) < 60_000]

    def stats(self) -> dict:
        elapsed = max(self.clock() - self._since, 1e-9)
        lat = np.asarray(self._latency_ms)
        return {"input_rate_hz": round(self._messages / elapsed, 2), "input_messages": self._messages,
                "latency_ms": {"median": round(float(np.median(lat)), 1) if lat.size else None,
                               "p95": round(float(np.percentile(lat, 95)), 1) if lat.size else None,
                               "samples": int(lat.size)}}


def _bounded(values, size: int, low: float) -> np.ndarray:
    out = np.zeros(size)
    got = np.nan_to_num(np.asarray(list(values)[:size], dtype=np.float64))
    out[:got.size] = np.clip(got, low, 1.0)
    return out


class BrowserKeys:
    """A key source for :class:`KeyTracker`: the page's held keys as real downs and ups, and its session keys."""

    def __init__(self, browser: BrowserInput):
        self.browser = browser
        self._held: frozenset[str] = frozenset()

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def poll(self) -> list[KeyEvent]:
        self.browser.pump()
        now = self.browser.keys
        events = [KeyEvent(k, True) for k in sorted(now - self._held)]
        events += [KeyEvent(k, False) for k in sorted(self._held - now)]
        self._held = now
        for key in self.browser.presses:   # a press and its release: the session sees one fresh press
            events += [KeyEvent(key, True), KeyEvent(key, False)]
        self.browser.presses = []
        return events


class BrowserKeyboardDevice(KeyboardDevice):
    """One arm from one hand's keys on the page (``layout`` left / right, as the keyboard device's)."""

    name = "browser-keyboard"

    def __init__(self, browser: BrowserInput, tracker: KeyTracker, layout: str = "left", **kwargs):
        super().__init__(tracker, layout=layout, **kwargs)
        self.browser = browser

    def settings(self) -> dict:
        return {**super().settings(), **self.browser.stats()}


class _PagePad:
    """The page's gamepad state behind the methods of pygame's Joystick that the gamepad device reads."""

    def __init__(self, browser: BrowserInput):
        self.browser = browser

    def get_axis(self, i: int) -> float:
        return float(self.browser.axes[i])

    def get_button(self, i: int) -> bool:
        return bool(self.browser.buttons[i] > 0.5)

    def get_numaxes(self) -> int:
        return PAD_AXES

    def get_numbuttons(self) -> int:
        return PAD_BUTTONS

    def get_name(self) -> str:
        return self.browser.pad_name or "browser gamepad"


class BrowserGamepadDevice(GamepadDevice):
    """The page's gamepad (the Gamepad API's standard mapping) driving one arm, with the gamepad device's layout."""

    name = "browser-gamepad"

    def __init__(self, browser: BrowserInput, layout: PadLayout | None = None, **kwargs):
        super().__init__(index=0, layout=layout, joystick=_PagePad(browser), **kwargs)
        self.browser = browser

    def connect(self) -> None:
        self._check_layout()

    def read(self):
        self.browser.pump()
        return self._frame()

    def disconnect(self) -> None:
        pass

    def settings(self) -> dict:
        return {**super().settings(), **self.browser.stats()}

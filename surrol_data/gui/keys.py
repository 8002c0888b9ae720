"""Keys of the GUI window as a key source for :class:`~surrol_data.collect.devices.keyboard.KeyTracker`.

The keyboard device and the session keys (redo, discard, save, end) read the window through it, exactly as
they read a terminal; the window's buttons press the session keys through :meth:`WindowKeys.press`.
"""

from __future__ import annotations

from collections import deque

from surrol_data.collect.devices.keyboard import KeyEvent

# Panda3D's names of keys that the key layouts and session keys spell differently.
_NAMES = {"escape": "esc", "arrow_up": "up", "arrow_down": "down", "arrow_left": "left", "arrow_right": "right",
          "enter": "enter", "space": " "}


class WindowKeys:
    """Key presses and releases of a ShowBase window (and the presses its buttons make)."""

    DOWN_EVENT, UP_EVENT = "surrol-key-down", "surrol-key-up"

    def __init__(self, base):
        self.base = base
        self._events: deque[KeyEvent] = deque()
        self.enabled = True   # off while a text field has the focus
        for thrower in getattr(base, "buttonThrowers", None) or []:
            thrower.node().set_button_down_event(self.DOWN_EVENT)
            thrower.node().set_button_up_event(self.UP_EVENT)
        base.accept(self.DOWN_EVENT, self._on, [True])
        base.accept(self.UP_EVENT, self._on, [False])

    def _on(self, down: bool, button: str) -> None:
        if not self.enabled or button.startswith("mouse") or button.startswith("wheel"):
            return
        name = _NAMES.get(button, button)
        if len(name) == 1 or name in _NAMES.values():
            self._events.append(KeyEvent(name.lower(), down))

    def press(self, key: str) -> None:
        """A press and release of ``key`` (what a click on a session button means)."""
        self._events.append(KeyEvent(key, True))
        self._events.append(KeyEvent(key, False))

    def hold(self, key: str, down: bool) -> None:
        """``key`` pressed (``down``) or released: what holding a button such as *take over* means."""
        self._events.append(KeyEvent(key, down))

    def start(self) -> None:
        self._events.clear()   # keys typed before play are not commands to the session

    def stop(self) -> None:
        pass

    def poll(self) -> list[KeyEvent]:
        # The session thread polls while the window's thread appends: take events one by one (atomic),
        # so none that arrives meanwhile is lost.
        events = []
        while self._events:
            events.append(self._events.popleft())
        return events

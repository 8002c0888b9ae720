"""Teleoperation devices by name: ``open_device("touch", side="right")`` builds any backend (not yet connected).

========== =============================================== ====================================
name       backend                                          provenance ``device``
========== =============================================== ====================================
touch      Touch stylus via OpenHaptics libHD (ctypes)      touch
keyboard   terminal or PyBullet GUI keys → virtual stylus   keyboard
gamepad    pygame joystick → virtual stylus                 gamepad
spacemouse 3Dconnexion puck via hidapi → virtual stylus     spacemouse
replay     frames of recorded device traces                 replay
operator   simulated human operator (motor-control model)   simulated-operator
========== =============================================== ====================================

Backends import their optional packages (pygame, hid, libHD) only when built or connected.
"""

from __future__ import annotations

from pathlib import Path

from typing import TYPE_CHECKING

from surrol_data.collect.devices.base import (BUTTON_CLUTCH, BUTTON_JAW, BUTTON_TAKEOVER, Device, DeviceError,
                                              DeviceFrame)

if TYPE_CHECKING:   # mapping imports devices.base, so importing it here at run time would be circular
    from surrol_data.collect.mapping import MappingSettings

DEVICE_NAMES = ("touch", "keyboard", "gamepad", "spacemouse", "replay", "operator")
HUMAN_DEVICES = ("touch", "keyboard", "gamepad", "spacemouse")   # paced in real time, may show a GUI
PLUGGED_DEVICES = ("touch", "gamepad", "spacemouse")   # hardware: found (or not) before a session starts
SIDES = ("left", "right")

__all__ = ["BUTTON_CLUTCH", "BUTTON_JAW", "BUTTON_TAKEOVER",
           "DEVICE_NAMES", "Device", "DeviceError", "DeviceFrame", "HUMAN_DEVICES", "PLUGGED_DEVICES",
           "check_devices", "default_sides", "open_device"]


def open_device(name: str, *, arm: int = 0, side: str | None = None, env=None, mapping: MappingSettings | None = None,
                skill: str = "expert", operator_id: str = "", seed: int = 0, trace: str | Path | None = None,
                key_tracker=None, library: str | Path | None = None) -> Device:
    """Build the device ``name`` for arm ``arm`` (0 = the task's first PSM); connect it with ``with dev:``.

    * ``touch``: ``side`` left/right/None picks the named stylus; ``library`` overrides libHD's path.
    * ``keyboard``: ``side`` picks the key layout (default: left hand for arm 0, right hand for arm 1);
      ``key_tracker`` shares one key source (terminal or GUI window) between devices and the session.
    * ``gamepad``: arm ``i`` uses joystick ``i``.  ``spacemouse``: one puck, arm 0 only.
    * ``replay``: ``trace`` is a trace file, trace folder or haptic dataset; arm ``i`` replays device ``i``.
    * ``operator``: the simulated operator; needs ``env`` (the unwrapped task env), ``skill``,
      ``operator_id``, ``mapping`` and ``seed``.
    """
    from surrol_data.collect.mapping import MappingSettings

    if name not in DEVICE_NAMES:
        raise ValueError(f"unknown device {name!r}; choose one of {', '.join(DEVICE_NAMES)}")
    if side is not None and side not in SIDES:
        raise ValueError(f"side must be one of {SIDES} or None, got {side!r}")
    if name == "touch":
        from surrol_data.collect.devices.touch import TouchDevice

        return TouchDevice(side=side, library=library)
    if name == "keyboard":
        from surrol_data.collect.devices.keyboard import KeyboardDevice, KeyTracker, TerminalKeys

        layout = side or SIDES[min(arm, 1)]
        return KeyboardDevice(key_tracker or KeyTracker(TerminalKeys()), layout=layout,
                              rotation_axis=(mapping or MappingSettings()).rotation_axis)
    if name == "gamepad":
        from surrol_data.collect.devices.gamepad import GamepadDevice

        return GamepadDevice(index=arm, rotation_axis=(mapping or MappingSettings()).rotation_axis)
    if name == "spacemouse":
        if arm != 0:
            raise ValueError("the spacemouse backend drives one arm; use two other devices for a bimanual task")
        from surrol_data.collect.devices.spacemouse import SpaceMouseDevice

        return SpaceMouseDevice(rotation_axis=(mapping or MappingSettings()).rotation_axis)
    if name == "replay":
        if trace is None:
            raise ValueError("the replay device needs a trace: a trace .npz, or a dataset recorded by a haptic "
                             "session (its meta/device_traces folder)")
        from surrol_data.collect.devices.replay import ReplayDevice

        return ReplayDevice(trace, device_index=arm)
    # operator
    if env is None:
        raise ValueError("the operator device watches the scene: pass env= (the unwrapped task env)")
    try:
        from surrol_data.collect.operator import SimulatedOperator
    except ImportError as e:
        raise DeviceError(f"the simulated operator is not available in this version ({e})") from None
    return SimulatedOperator(env, skill, operator_id, mapping or MappingSettings(), seed, arm=arm)


def default_sides(name: str, n_devices: int) -> list[str | None]:
    """The device side of each arm when none is given: two Touch styli are the named Right (PSM1) and Left (PSM2);
    any other device is the default one of its kind."""
    return ["right", "left"] if n_devices == 2 and name == "touch" else [None] * n_devices


def check_devices(name: str, sides, library: str | Path | None = None) -> None:
    """Open and close the hardware device ``name`` once per side: a missing SDK, driver or extra, or a device that is
    not plugged in, is a :class:`DeviceError` saying what to do, before a session spends seconds on its env and
    dataset. Other devices (keyboard, replay, operator) need nothing checked."""
    if name not in PLUGGED_DEVICES:
        return
    for arm, side in enumerate(sides):
        device = open_device(name, arm=arm, side=side, library=library)
        device.connect()
        device.disconnect()

"""Device backends without hardware: the touch binding against a compiled stand-in libHD, keyboard through a
real pseudo-terminal and injected GUI key events, gamepad and SpaceMouse with injected joystick / HID reports."""

from __future__ import annotations

import os
import struct

import numpy as np
import pytest

from libhd_standin_build import build_libhd, write_script
from surrol_data.collect.devices import DeviceError, open_device
from surrol_data.collect.devices.base import BUTTON_CLUTCH, BUTTON_JAW, DeviceFrame
from surrol_data.collect.devices.keyboard import KeyboardDevice, KeyTracker, PyBulletKeys, TerminalKeys
from surrol_data.collect.devices.replay import ReplayDevice
from surrol_data.collect.devices.spacemouse import SpaceMouseDevice, parse_report
from surrol_data.collect.devices.trace import mapping_from_dict, read_trace, write_trace
from surrol_data.collect.haptic_source import parse_mapping
from surrol_data.collect.mapping import ActionMapper, MappingSettings, frame_defaults

# ---------------------------------------------------------------------------------------------- touch


def _frames(n, start=0.0, buttons=0):
    return [DeviceFrame(np.array([start + i, 2.0 * i, -i / 3]), np.array([0.0, 0.1, 0.01 * i]), buttons, i)
            for i in range(n)]


@pytest.fixture()
def standin(tmp_path, monkeypatch):
    lib = build_libhd(tmp_path)   # a fresh file per test: dlopen gives each its own stand-in state
    monkeypatch.setenv("LIBHD_STANDIN_LOG", str(tmp_path / "calls.log"))
    monkeypatch.delenv("LIBHD_STANDIN_UNPLUG_AFTER", raising=False)
    return lib, tmp_path


def test_touch_reads_scripted_frames_of_two_named_devices(standin, monkeypatch):
    lib, tmp = standin
    left, right = _frames(4, 0.0, BUTTON_JAW), _frames(3, 100.0, BUTTON_CLUTCH)
    monkeypatch.setenv("LIBHD_STANDIN_SCRIPT", str(write_script(tmp / "s.txt", {"Left": left, "Right": right})))
    with open_device("touch", side="left", library=lib) as dl, open_device("touch", side="right", library=lib) as dr:
        got_l = [dl.read() for _ in range(5)]
        got_r = [dr.read() for _ in range(3)]
    for got, want in zip(got_l[:4] + got_r, left + right, strict=True):
        np.testing.assert_array_equal(got.position_mm, want.position_mm)   # exact doubles through ctypes
        np.testing.assert_array_equal(got.gimbal_rad, want.gimbal_rad)
        assert got.buttons == want.buttons
    np.testing.assert_array_equal(got_l[4].position_mm, left[-1].position_mm)   # past the end: the stylus rests
    calls = (tmp / "calls.log").read_text().split()
    # the scheduler is stopped around the second hdInitDevice and around each hdDisableDevice
    assert calls == ["init", "Left", "start", "stop", "init", "Right", "start",
                     "stop", "disable", "Right", "start", "stop", "disable", "Left"]


def test_touch_missing_library_names_the_sdk_and_the_variable(tmp_path, monkeypatch):
    monkeypatch.setenv("SURROL_LIBHD", str(tmp_path / "nowhere" / "libHD.so"))
    with pytest.raises(DeviceError, match="OpenHaptics.*SURROL_LIBHD"):
        open_device("touch").connect()
    fake = tmp_path / "libHD.so"
    fake.write_text("not a library")
    with pytest.raises(DeviceError, match="cannot load libHD.*OpenHaptics"):
        open_device("touch", library=fake).connect()


def test_touch_unknown_device_and_unplug_mid_read(standin, monkeypatch):
    lib, tmp = standin
    monkeypatch.setenv("LIBHD_STANDIN_SCRIPT", str(write_script(tmp / "s.txt", {"default": _frames(10)})))
    with pytest.raises(DeviceError, match="cannot initialise Touch device Right.*Touch_Setup"):
        open_device("touch", side="right", library=lib).connect()
    monkeypatch.setenv("LIBHD_STANDIN_UNPLUG_AFTER", "3")
    with open_device("touch", library=lib) as dev:
        for _ in range(3):
            dev.read()
        with pytest.raises(DeviceError, match="stopped answering.*communication error"):
            dev.read()


# ---------------------------------------------------------------------------------------------- keyboard


def test_keyboard_in_a_real_terminal_drives_the_tool_through_the_mapping():
    master, slave = os.openpty()
    clock = [0.0]
    tracker = KeyTracker(TerminalKeys(fd=slave), hold_s=0.5, clock=lambda: clock[0])
    dev = KeyboardDevice(tracker, layout="left")
    mapper = ActionMapper(MappingSettings(**frame_defaults("robot")))   # device axes straight into action axes
    try:
        with dev:
            mapper(dev.read())                        # reference frame
            os.write(master, b"dc")                   # d: tool +y, c: jaw button
            step = mapper(dev.read())
            assert step.arm[1] > 0 and step.arm[0] == 0 and step.arm[2] == 0
            assert step.jaw_button and step.arm[4] == pytest.approx(0.5)
            # 8 mm of stylus per step (40 mm/s × 0.2 s) × motion scale 0.5 = 4 mm of tool = 0.4 action units
            assert step.arm[1] == pytest.approx(0.4)
            clock[0] = 0.4                            # still within the auto-repeat hold
            assert mapper(dev.read()).arm[1] == pytest.approx(0.4)
            clock[0] = 1.0                            # no repeat for 0.6 s: released
            step = mapper(dev.read())
            assert step.arm[1] == 0 and not step.jaw_button
            os.write(master, b"v\x1b[Ar")             # clutch, an arrow key, the session's redo key
            step = mapper(dev.read())
            assert step.clutch and not np.any(step.arm[:4])
            assert tracker.pop_pressed() == ["d", "c", "v", "up", "r"]
    finally:
        os.close(master)
        os.close(slave)


def test_keyboard_needs_a_terminal(tmp_path):
    with open(tmp_path / "f", "w") as fh, pytest.raises(DeviceError, match="needs a terminal"):
        KeyboardDevice(KeyTracker(TerminalKeys(fd=fh.fileno()))).connect()


class _GuiClient:
    """Injected PyBullet GUI keyboard events (a DIRECT client has no window to type into)."""

    def __init__(self, script):
        self.script = list(script)

    def getKeyboardEvents(self):   # noqa: N802 (pybullet's name)
        return self.script.pop(0) if self.script else {}


def test_keyboard_from_the_pybullet_window_uses_real_downs_and_ups():
    down, trig, rel = PyBulletKeys.KEY_IS_DOWN, PyBulletKeys.KEY_WAS_TRIGGERED, PyBulletKeys.KEY_WAS_RELEASED
    client = _GuiClient([{ord("i"): down | trig, ord("n"): down | trig}, {ord("i"): down}, {ord("i"): rel},
                         {27: trig}])
    tracker = KeyTracker(PyBulletKeys(client))
    dev = KeyboardDevice(tracker, layout="right")
    frames = [dev.read() for _ in range(3)]
    assert frames[0].position_mm[1] == pytest.approx(8.0) and frames[0].buttons == BUTTON_JAW
    assert frames[1].position_mm[1] == pytest.approx(16.0)   # held (no time-out for real key states)
    assert frames[2].position_mm[1] == pytest.approx(16.0) and frames[2].buttons == 0
    tracker.update()
    assert tracker.pop_pressed() == ["i", "n", "esc"]


# ---------------------------------------------------------------------------------------------- gamepad


class _Joystick:
    def __init__(self):
        self.axes = [0.0] * 6
        self.buttons = [0] * 8

    def get_numaxes(self):
        return len(self.axes)

    def get_numbuttons(self):
        return len(self.buttons)

    def get_axis(self, i):
        return self.axes[i]

    def get_button(self, i):
        return self.buttons[i]

    def get_name(self):
        return "injected pad"

    def get_instance_id(self):
        return 7


def test_gamepad_sticks_buttons_and_unplug(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame = pytest.importorskip("pygame")
    js = _Joystick()
    dev = open_device("gamepad")
    dev._joystick, dev._injected = js, True   # no pad on the test machine: inject one
    with dev:
        js.axes[0] = 0.1                                   # inside the dead zone
        assert np.all(dev.read().position_mm == 0)
        js.axes[0], js.buttons[0], js.buttons[1] = 1.0, 1, 1
        frame = dev.read()
        assert frame.position_mm[0] == pytest.approx(8.0) and frame.buttons == BUTTON_JAW | BUTTON_CLUTCH
        js.buttons[4] = 1                                  # left shoulder: yaw
        assert dev.read().gimbal_rad[2] > 0
        pygame.event.post(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=7))
        with pytest.raises(DeviceError, match="unplugged"):
            dev.read()


def test_gamepad_missing_is_a_clear_error(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pytest.importorskip("pygame")
    with pytest.raises(DeviceError, match="gamepad 3 not found"):
        open_device("gamepad", arm=3).connect()


# ---------------------------------------------------------------------------------------------- spacemouse


class _Hid:
    def __init__(self, reports):
        self.reports = list(reports)

    def read(self, n):
        if self.reports and self.reports[0] == "unplug":
            raise OSError("read error")
        return list(self.reports.pop(0)) if self.reports else []


def test_spacemouse_parses_reports_of_old_and_new_models():
    state = {"translation": np.zeros(3), "rotation": np.zeros(3), "buttons": 0}
    parse_report(struct.pack("<Bhhh", 1, 350, -175, 0), state)
    np.testing.assert_allclose(state["translation"], [1.0, -0.5, 0.0])
    parse_report(struct.pack("<Bhhh", 2, 0, 0, 350), state)
    np.testing.assert_allclose(state["rotation"], [0, 0, 1.0])
    parse_report(struct.pack("<Bhhhhhh", 1, 0, 0, 350, 35, 0, 0), state)   # 13-byte report: both at once
    np.testing.assert_allclose(state["translation"], [0, 0, 1.0])
    np.testing.assert_allclose(state["rotation"], [0.1, 0, 0])
    parse_report(bytes([3, 2, 0]), state)
    assert state["buttons"] == 2


def test_spacemouse_device_integrates_and_reports_unplug():
    hid = _Hid([struct.pack("<Bhhh", 1, 350, 0, 0), struct.pack("<Bhhh", 2, 0, 0, -350), bytes([3, 1]), b"",
                "unplug"])   # b"": nothing pending (a non-blocking read returns no report)
    dev = SpaceMouseDevice(hid_device=hid)
    with dev:
        frame = dev.read()   # drains the three reports
        assert frame.position_mm[0] == pytest.approx(8.0) and frame.buttons == BUTTON_JAW
        assert frame.gimbal_rad[2] > 0
        with pytest.raises(DeviceError, match="unplugged"):
            dev.read()


# ---------------------------------------------------------------------------------------------- traces, registry


def test_trace_roundtrip_and_replay_device(tmp_path):
    frames = _frames(5)
    mapping = MappingSettings(motion_scale=0.3, axis_sign=(1.0, -1.0, 1.0))
    path = write_trace(tmp_path / "t" / "episode_000000.npz", [frames], np.zeros((5, 5)),
                       {"seed": 42, "mapping": [mapping.as_dict()]})
    trace = read_trace(path)
    assert trace.seed == 42 and len(trace) == 5 and trace.mapping(0) == mapping
    dev = ReplayDevice(tmp_path / "t")
    with dev:
        assert dev.start_episode(0).seed == 42
        got = [dev.read() for _ in range(5)]
        assert dev.exhausted
        with pytest.raises(DeviceError, match="ended after 5 frames"):
            dev.read()
    assert [f.to_row() for f in got] == [f.to_row() for f in frames]
    with pytest.raises(DeviceError, match="no device traces"):
        ReplayDevice(tmp_path / "empty_dir_that_is_missing")


def test_mapping_overrides_and_registry_errors():
    m = parse_mapping(["motion_scale=0.25", "axis_permutation=0,1,2", "axis_sign=1,-1,1", "rotation_axis=1"])
    assert m.motion_scale == 0.25 and m.axis_permutation == (0, 1, 2) and m.rotation_axis == 1
    assert mapping_from_dict(m.as_dict()) == m
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_mapping(["speed=2"])
    with pytest.raises(ValueError, match="needs 3"):
        parse_mapping(["axis_sign=1,1"])
    with pytest.raises(ValueError, match="permutation"):
        parse_mapping(["axis_permutation=0,0,1"])
    with pytest.raises(ValueError, match="unknown device 'mouse'"):
        open_device("mouse")
    with pytest.raises(ValueError, match="needs a trace"):
        open_device("replay")
    with pytest.raises(ValueError, match="pass env="):
        open_device("operator")

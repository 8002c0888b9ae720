"""The endoscope view the right way up and framed on the work, and teleoperation in its frame (issue 29).

* the camera: image up is the ECM's EEF x axis, as the reference renders it, so world vertical is image up on every
  task (measured on the pixels of real renders); the PSM scenes fill the image with no void and no table edge at
  its border, at 640×480 and 128×128, for TinyRenderer and (where it can open a buffer) Panda3D;
* the hand → screen direction: for every device class and every kind of task and arm, a hand (or key, stick, puck)
  motion right / up / away moves the tool's image right / up / deeper, measured by projecting the tool tip (the
  endoscope, on ECM tasks) before and after the step.
"""

from __future__ import annotations

import math
import os
import struct

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.devices.base import Device, DeviceFrame
from surrol_data.collect.devices.keyboard import KeyboardDevice, KeyTracker, TerminalKeys
from surrol_data.collect.devices.spacemouse import SpaceMouseDevice
from surrol_data.collect.devices.trace import mapping_from_dict, write_trace
from surrol_data.collect.haptic_source import collect_haptic, parse_mapping
from surrol_data.collect.mapping import ActionMapper, MappingSettings, view_to_action
from surrol_data.envs import TASKS, env_id
from surrol_data.envs import ecm_kinematics as ekin
from surrol_data.envs.camera import TAN_HALF_FOV, camera_axes, make_camera
from surrol_data.envs.ecm import PSM_SCENE_VIEW_TARGET
from surrol_data.envs.objects import TABLE_TOP_Z
from surrol_data.envs.physics import pb
from surrol_data.envs.units import SCALING

ECM_TASKS = ("ECMReach", "MisOrient", "StaticTrack", "ActiveTrack")
UP_TOLERANCE_DEG = 5.0
DIRECTION_TOLERANCE_DEG = 3.0
# Hand motions in the device frame every device shares (x right, y up, z towards the user), and where the tool's
# image must go: (right, up, deeper) in the camera's coordinates.
HAND = {"right": (1.0, 0.0, 0.0), "up": (0.0, 1.0, 0.0), "away": (0.0, 0.0, -1.0)}
SCREEN = {"right": (1.0, 0.0, 0.0), "up": (0.0, 1.0, 0.0), "away": (0.0, 0.0, 1.0)}


# ---------------------------------------------------------------------------------------------- the camera

def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _pose(xyz, rot):
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot, xyz
    return t


def _urdf_end_link_in_rcm(q):
    """The reference's ecm.urdf chain (joint origins as its file gives them) up to ecm_end_link, in the RCM frame."""
    def turn(a):
        return _pose([0, 0, 0], _rpy(0, 0, a))
    t = _pose([0.6126, 0, 0.1016], _rpy(0, -np.pi / 2, 0)) @ turn(q[0])          # ecm_yaw_joint
    t = t @ _pose([0, 0, 0], _rpy(-np.pi / 2, -np.pi / 2, 0)) @ turn(q[1])        # ecm_pitch_end_joint
    t = t @ _pose([0, 0.3822, 0], _rpy(np.pi / 2, 0, 0)) @ _pose([0, 0, q[2]], np.eye(3))   # insertion
    t = t @ _pose([0, 0, 0.3829], np.eye(3)) @ turn(q[3])                         # ecm_tool_joint; end = tool
    rcm = _pose([0.6126, 0, 0.1016], _rpy(0, 0, -np.pi / 2))                       # ecm_remote_center_joint
    return np.linalg.inv(rcm) @ t


@pytest.mark.parametrize("q", [(0, 0, 0, 0), (0.3, 0.6, 0.04, 0.2), (-0.5, -0.2, 0.1, -0.7)])
def test_image_up_is_the_reference_end_links_x_axis(q):
    # The reference renders with up = the URDF end link's x axis. That link is DH frame 4, so up must be x4.
    urdf = _urdf_end_link_in_rcm(q)
    np.testing.assert_allclose(ekin.ecm_fk(q), urdf, atol=1e-9)
    axes = camera_axes(urdf)
    np.testing.assert_allclose([-v for v in axes.down], urdf[:3, 0], atol=1e-12)
    np.testing.assert_allclose(axes.forward, urdf[:3, 2], atol=1e-12)
    np.testing.assert_allclose(np.cross(axes.right, axes.down), axes.forward, atol=1e-12)   # right-handed


def _marker(client, position, scale):
    vis = client.createVisualShape(pb.GEOM_SPHERE, radius=0.002 * scale, rgbaColor=(1, 0, 1, 1))
    return client.createMultiBody(0.0, -1, vis, [v * scale for v in position])


def _view_env(task):
    """(env, endoscope pose, scene scale) of a task built to be rendered; MisOrient at its upright pose."""
    env = gym.make(env_id(task), render_mode="rgb_array")
    env.reset(seed=0)
    u = env.unwrapped
    if task == "MisOrient":   # the task starts rolled on purpose; its goal is the upright view
        from surrol_data.envs.tasks.mis_orient import NATURAL_JOINTS

        u.ecm.reset_joints(NATURAL_JOINTS)
    if task in ECM_TASKS:
        u._sync_scene()
    return env, u.endoscope_pose(), 1.0 if task in ECM_TASKS else SCALING


def _border_points(image, pose, size):
    """World points (real metres) seen by the pixels of the image's outermost rows and columns, and their ids."""
    w, h = size
    axes = camera_axes(pose)
    rows, cols = np.indices((h, w))
    border = (rows == 0) | (rows == h - 1) | (cols == 0) | (cols == w - 1)
    x = ((cols[border] + 0.5) / w * 2 - 1) * TAN_HALF_FOV * w / h
    y = ((rows[border] + 0.5) / h * 2 - 1) * TAN_HALF_FOV
    d = image.depth[border][:, None]
    return (np.asarray(axes.eye) + d * (np.asarray(axes.forward) + x[:, None] * np.asarray(axes.right)
                                        + y[:, None] * np.asarray(axes.down))), image.segmentation[border]


@pytest.mark.parametrize("task", TASKS)
def test_the_view_is_upright_and_framed(task):
    env, pose, scale = _view_env(task)
    client = env.unwrapped.client
    try:
        # No void at the border (at 640×480 and at 128×128) and, over the PSM tasks, only the table top and what
        # stands on it: a border pixel below the top would be the table's edge face.
        for size in ((640, 480), (128, 128)):
            image = make_camera(client, size, scale, "tiny").render(pose, depth=True, segmentation=True)
            points, ids = _border_points(image, pose, size)
            assert (ids >= 0).all(), f"{task} at {size}: {(ids < 0).sum()} border pixels see the void"
            if task not in ECM_TASKS:
                assert points[:, 2].min() > TABLE_TOP_Z - 0.002, f"{task} at {size}: the table's edge is in view"
        # World up is image up: two markers on the vertical through the point the view is centred on, 2 cm apart
        # (above the pegs and blocks, which would hide them); the upper one must be drawn straight above.
        axes = camera_axes(pose)
        base = (np.asarray(PSM_SCENE_VIEW_TARGET) + [0, 0, 0.04] if scale != 1.0
                else np.asarray(axes.eye) + 0.3 * np.asarray(axes.forward))
        low, high = _marker(client, base, scale), _marker(client, base + [0, 0, 0.02], scale)
        seg = make_camera(client, (640, 480), scale, "tiny").render(pose, segmentation=True).segmentation
        (r0, c0), (r1, c1) = (np.argwhere(seg == body).mean(axis=0) for body in (low, high))
        angle = math.degrees(math.atan2(c1 - c0, r0 - r1))   # 0: straight up on the screen
        assert abs(angle) < UP_TOLERANCE_DEG, f"{task}: world up is drawn {angle:.1f}° from image up"
        up = np.array([0.0, 0.0, 1.0])
        analytic = math.degrees(math.atan2(up @ np.array(axes.right), -(up @ np.array(axes.down))))
        assert abs(analytic) < UP_TOLERANCE_DEG
    finally:
        env.close()


def test_panda3d_view_has_no_void_columns_and_is_upright():
    from surrol_data.render.display import unavailable_reason

    if unavailable_reason() is not None:
        pytest.skip(str(unavailable_reason()))
    env = gym.make(env_id("PegTransfer"), camera=True, camera_size=(640, 480), camera_renderer="panda3d")
    try:
        env.reset(seed=0)
        u = env.unwrapped
        image = u.endoscope.camera.render(u.endoscope.ecm.eef_world, depth=True, segmentation=True)
        assert (image.segmentation[:, [0, -1]] >= 0).all() and (image.segmentation[[0, -1], :] >= 0).all()
        # The board stands upright in the picture: its top face is drawn above its front face (the face towards
        # the viewer): rows of the board's pixels higher on the board in the world are higher in the image.
        points, ids = _border_points(image, u.endoscope.ecm.eef_world, (640, 480))
        assert points[:, 2].min() > TABLE_TOP_Z - 0.002
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------- hand → screen

def _camera_coords(axes, p):
    d = np.asarray(p, np.float64) - np.asarray(axes.eye)
    return np.array([d @ np.asarray(axes.right), -(d @ np.asarray(axes.down)), d @ np.asarray(axes.forward)])


def _tool_point(env, info, arm):
    """Where the tool is (world, real metres): the PSM's tip, or the endoscope itself on an ECM task."""
    u = env.unwrapped
    if u.action_space.shape[0] % 5:
        return np.array(u.ecm.eef_position_world())
    return np.asarray(info["tip_position"], np.float64).reshape(-1, 3)[arm]


def _angle(a, b):
    return math.degrees(math.acos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))


_ENVS: dict = {}


@pytest.fixture(scope="module", autouse=True)
def _close_envs():
    yield
    for env in _ENVS.values():
        env.close()
    _ENVS.clear()


def _env(task):
    """One env per task for the direction checks: every check resets it with seed 0 (a reset rebuilds the same
    scene whatever ran before)."""
    if task not in _ENVS:
        _ENVS[task] = gym.make(env_id(task))
    return _ENVS[task]


def _screen_motion(task, arm, frames, mapping=None):
    """Camera-frame displacement (right, up, deeper; metres) of arm ``arm``'s tool when the device's two frames
    are mapped (the first is the reference, as at the start of every attempt) and the action is stepped."""
    env = _env(task)
    _, info = env.reset(seed=0)
    u = env.unwrapped
    mapper = ActionMapper(mapping or MappingSettings())
    axes = camera_axes(u.endoscope_pose())
    view = view_to_action(u, arm) if mapper.settings.frame == "camera" else None
    mapper(frames[0], view)
    step = mapper(frames[1], view)
    action = np.zeros(u.action_space.shape, np.float32)
    if action.size % 5:          # an ECM task: the hand moves the camera (its direction is what is checked)
        action[:] = step.arm[:action.size]
    else:
        action[4::5] = 1.0
        action[5 * arm:5 * arm + 5] = step.arm
    before = _tool_point(env, info, arm)
    _, _, _, _, info = env.step(action)
    return _camera_coords(axes, _tool_point(env, info, arm)) - _camera_coords(axes, before)


def _pair(direction, mm=2.0):
    """The reference frame and one ``mm`` along ``direction`` of the device frame."""
    return [DeviceFrame(np.zeros(3), np.zeros(3), 0, 0.0),
            DeviceFrame(mm * np.asarray(HAND[direction]), np.zeros(3), 0, 0.2)]


def _assert_on_screen(task, arm, direction, motion):
    assert np.linalg.norm(motion) > 1e-5, f"{task} arm {arm}: the tool did not move for a hand motion {direction}"
    angle = _angle(motion, np.asarray(SCREEN[direction]))
    assert angle < DIRECTION_TOLERANCE_DEG, (f"{task} arm {arm}: hand {direction} moved the tool's image "
                                             f"{np.round(motion * 1000, 2)} mm (right, up, deeper), {angle:.1f}° off")


KINDS = [("NeedlePick", 0), ("PegTransfer", 0), ("NeedleRegrasp", 0), ("NeedleRegrasp", 1), ("BiPegTransfer", 0),
         ("BiPegTransfer", 1), ("ECMReach", 0), ("StaticTrack", 0), ("ActiveTrack", 0)]


@pytest.mark.parametrize("task,arm", KINDS)
def test_hand_motion_moves_the_tool_the_same_way_on_screen(task, arm):
    for direction in HAND:
        _assert_on_screen(task, arm, direction, _screen_motion(task, arm, _pair(direction)))


def test_old_traces_replay_in_the_robot_frame_which_is_not_the_screens():
    # Traces recorded before the camera frame name no frame: they replay with the robot-frame map they were made
    # with (hand up drove world up, which on this view also comes towards the lens, 40° off image up).
    legacy = MappingSettings().as_dict()
    legacy.update(axis_permutation=[2, 0, 1], axis_sign=[1.0, 1.0, 1.0])
    del legacy["frame"]
    old = mapping_from_dict(legacy)
    assert old.frame == "robot" and parse_mapping(["frame=robot"]) == old
    motion = _screen_motion("NeedlePick", 0, _pair("up"), old)
    assert _angle(motion, np.asarray(SCREEN["up"])) > 20.0
    with pytest.raises(ValueError, match="frame must be one of camera, robot"):
        parse_mapping(["frame=world"])


# ---------------------------------------------------------------------------------------------- every device class
# Each device's natural right / up / away input (a stylus move, a key, a stick, a puck push) goes through the
# device, the mapping and the env; the tool's image must move that way.

def _check_device(read_pair, task="NeedlePick", arm=0):
    for direction in HAND:
        _assert_on_screen(task, arm, direction, _screen_motion(task, arm, read_pair(direction)))


def test_touch_stylus(tmp_path, monkeypatch):
    from libhd_standin_build import build_libhd, write_script

    from surrol_data.collect.devices import open_device

    lib = build_libhd(tmp_path)
    monkeypatch.setenv("LIBHD_STANDIN_LOG", str(tmp_path / "calls.log"))
    monkeypatch.delenv("LIBHD_STANDIN_UNPLUG_AFTER", raising=False)

    def read_pair(direction, side="right"):
        script = {side.capitalize(): _pair(direction, mm=4.0)}
        monkeypatch.setenv("LIBHD_STANDIN_SCRIPT", str(write_script(tmp_path / f"{side}_{direction}.txt", script)))
        with open_device("touch", side=side, library=lib) as dev:
            return [dev.read(), dev.read()]

    _check_device(read_pair)
    _check_device(lambda d: read_pair(d, "left"), "BiPegTransfer", 1)


@pytest.mark.parametrize("layout,arm,task", [("left", 0, "NeedlePick"), ("right", 1, "NeedleRegrasp")])
def test_keyboard_in_a_terminal(layout, arm, task):
    keys = {"left": {"right": b"d", "up": b"w", "away": b"e"}, "right": {"right": b"l", "up": b"i", "away": b"o"}}

    def read_pair(direction):
        master, slave = os.openpty()
        try:
            with KeyboardDevice(KeyTracker(TerminalKeys(fd=slave), hold_s=0.5, clock=lambda: 0.0),
                                layout=layout) as dev:
                first = dev.read()
                os.write(master, keys[layout][direction])
                return [first, dev.read()]
        finally:
            os.close(master)
            os.close(slave)

    _check_device(read_pair, task, arm)


class _Base:
    """The ShowBase calls WindowKeys makes; the window's key events are injected through its handler."""

    buttonThrowers: list = []

    def __init__(self):
        self.handlers = {}

    def accept(self, event, handler, args):
        self.handlers[event] = (handler, args)


@pytest.mark.parametrize("task", ["NeedlePick", "ECMReach"])
def test_gui_window_keys(task):
    from surrol_data.gui.keys import WindowKeys

    keys = {"right": "d", "up": "w", "away": "e"}

    def read_pair(direction):
        base = _Base()
        window = WindowKeys(base)
        dev = KeyboardDevice(KeyTracker(window), layout="left")
        first = dev.read()
        handler, args = base.handlers[WindowKeys.DOWN_EVENT]
        handler(*args, keys[direction])
        return [first, dev.read()]

    _check_device(read_pair, task)


def test_gamepad_sticks(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pytest.importorskip("pygame")
    from test_devices import _Joystick

    from surrol_data.collect.devices import open_device

    push = {"right": (0, 1.0), "up": (3, -1.0), "away": (1, -1.0)}   # SDL: a stick pushed up/forward reads −1

    def read_pair(direction):
        js = _Joystick()
        dev = open_device("gamepad")
        dev._joystick, dev._injected = js, True
        with dev:
            first = dev.read()
            axis, value = push[direction]
            js.axes[axis] = value
            return [first, dev.read()]

    _check_device(read_pair)


def test_spacemouse_puck():
    from test_devices import _Hid

    push = {"right": (350, 0, 0), "up": (0, 0, -350), "away": (0, -350, 0)}   # HID: x right, y towards you, z down

    def read_pair(direction):
        dev = SpaceMouseDevice(hid_device=_Hid([b"", struct.pack("<Bhhh", 1, *push[direction]), b""]))
        with dev:
            return [dev.read(), dev.read()]

    _check_device(read_pair)


def test_replayed_trace(tmp_path):
    from surrol_data.collect.devices.replay import ReplayDevice

    def read_pair(direction):
        path = write_trace(tmp_path / direction / "episode_000000.npz", [_pair(direction)], np.zeros((2, 5)),
                           {"seed": 0, "mapping": [MappingSettings().as_dict()]})
        with ReplayDevice(path) as dev:
            assert dev.start_episode(0).mapping(0).frame == "camera"
            return [dev.read(), dev.read()]

    _check_device(read_pair)


@pytest.mark.parametrize("task,arm", [("NeedlePick", 0), ("BiPegTransfer", 1), ("ECMReach", 0), ("StaticTrack", 0)])
def test_simulated_operator_plans_its_hand_in_the_camera_frame(task, arm):
    # The operator's internal model inverts the session's mapping: the hand motion it plans to move the tool
    # along the image's right / up / deeper, mapped as the session maps it, moves the tool that way on screen.
    from surrol_data.collect.operator import SimulatedOperator

    env = gym.make(env_id(task))
    try:
        env.reset(seed=0)
        u = env.unwrapped
        exact = {"internal_gain": 1.0, "frame_rotation_deg": 0.0}   # a person whose model of the mapping is right
        op = SimulatedOperator(u, "expert", "e", MappingSettings(), 0, arm=arm, overrides=exact)
        action_of_image = view_to_action(u, arm)
        for direction, screen in SCREEN.items():
            tool = action_of_image @ np.asarray(screen) * 3.0       # 3 mm of tool along the screen direction
            hand = op._hand_motion_for(tool, 0.0)[:3]
            frames = [DeviceFrame(np.zeros(3), np.zeros(3), 0, 0.0), DeviceFrame(hand, np.zeros(3), 0, 0.2)]
            _assert_on_screen(task, arm, direction, _screen_motion(task, arm, frames))
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------- the session

class _Scripted(Device):
    """A device that rests, then moves right, up and away, one step each."""

    name = "spacemouse"

    def __init__(self, mm=2.0):
        self.path = [np.zeros(3)]
        for d in HAND:
            self.path.append(self.path[-1] + mm * np.asarray(HAND[d]))
        self.k = 0

    def connect(self):
        self.k = 0

    def disconnect(self):
        pass

    def read(self):
        p = self.path[min(self.k, len(self.path) - 1)]
        self.k += 1
        return DeviceFrame(p.copy(), np.zeros(3), 0, 0.2 * self.k)


@pytest.mark.parametrize("task", ["NeedlePick", "BiPegTransfer", "ECMReach", "StaticTrack"])
def test_a_haptic_session_maps_the_hand_in_the_camera_frame_and_records_it(task, tmp_path):
    import json

    from surrol_data.datasets.reader import DatasetReader

    n_arms = 2 if task == "BiPegTransfer" else 1
    tools = []

    def on_step(env, step, obs, info, flags):
        tools.append([_tool_point(env, info, arm) for arm in range(n_arms)])

    env = gym.make(env_id(task))
    _, info = env.reset(seed=0)
    axes = camera_axes(env.unwrapped.endoscope_pose())
    tools.append([_tool_point(env, info, arm) for arm in range(n_arms)])
    env.close()
    collect_haptic(task, 1, tmp_path / "ds", device=[_Scripted() for _ in range(n_arms)], seed=0, max_steps=4,
                   keep_failures=True, progress=False, gui=False, realtime=False, on_step=on_step)
    for arm in range(n_arms):
        for k, direction in enumerate(HAND, start=1):
            motion = _camera_coords(axes, tools[k + 1][arm]) - _camera_coords(axes, tools[k][arm])
            _assert_on_screen(task, arm, direction, motion)
    settings = json.loads(DatasetReader(tmp_path / "ds").episodes["device_settings"].iloc[0])
    assert settings["mapping_frames"] == ["camera"] * n_arms and settings["camera_version"] == 2


def test_an_env_made_without_render_mode_is_refused_by_the_view_not_left_to_hang():
    """Such a world has no visual shapes and its PyBullet server no renderer: Panda3D's mirror of the scene asked for
    its visual shapes and never got an answer. The view says what to do instead."""
    from surrol_data.render.env_view import EnvEndoscope

    env = gym.make(env_id("NeedlePick"))
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="render_mode='rgb_array'"):
            EnvEndoscope(env)
    finally:
        env.close()

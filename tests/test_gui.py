"""The training GUI driven end to end: open, choose NeedlePick, play with the simulated operator, save an
episode, exit; the dataset validates. Offscreen in-process, and on a real X display under Xvfb through the CLI.

Skipped (naming the Debian packages) where Panda3D cannot render: EGL/Mesa for offscreen, xvfb for the window.
"""

import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from surrol_data.render.display import unavailable_reason
pytestmark = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))

SAVE_AT_STEP = 12   # the scripted trainee saves attempt 1 here, mid-task (so it is saved, not a success)


def test_gui_play_save_exit_records_a_valid_dataset(tmp_path):
    from surrol_data.collect.haptic_source import SKILLS
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.validate import validate_dataset
    from surrol_data.gui.app import DEVICES, TrainingApp

    app = TrainingApp(out=tmp_path, offscreen=True, size=(640, 360))
    clicks, seen = [], []

    def trainee(task):
        """Clicks as a person would, watching the HUD: save attempt 1 mid-way, exit during attempt 2."""
        hud = app.hud
        if hud.attempt == 1 and hud.steps == SAVE_AT_STEP and "save" not in clicks:
            seen.append(app.hud_text.getText())
            clicks.append("save")
            app.buttons["save"].commandFunc(None)
        elif hud.attempt == 2 and hud.steps == 3 and "exit" not in clicks:
            clicks.append("exit")
            app.buttons["exit"].commandFunc(None)
        return task.cont

    app.base.taskMgr.add(trainee, "scripted-trainee")
    app.cards["NeedlePick"].commandFunc(None)           # a click on the task's card
    app.device_menu.set(DEVICES.index("operator"))      # as choosing in the menus does
    app.skill_menu.set(SKILLS.index("expert"))
    app.operator_entry.enterText("trainee-7")
    app._typing(False)                                  # the field loses the focus: its text is taken
    assert app.task == "NeedlePick" and app.device == "operator" and app.skill == "expert"
    app.buttons["play"].commandFunc(None)
    app.run()

    assert clicks == ["save", "exit"]
    assert "simulated operator (expert)" in seen[0]   # the HUD says who operates, and at which skill
    root = tmp_path / "NeedlePick"
    assert validate_dataset(root) == []
    reader = DatasetReader(root)
    episodes = reader.episodes
    assert len(episodes) == 1
    row = episodes.iloc[0]
    assert row["source"] == "haptic" and row["device"] == "simulated-operator"
    assert row["skill"] == "expert" and row["operator_id"] == "trainee-7"
    # Saved as it stood: the steps before the click, no more.
    traj = reader.trajectory(int(row["episode_index"]))
    assert len(traj.action) == SAVE_AT_STEP
    # And as its actions give it without a window: drawing the view left the episode as it was (the scene is read
    # without PyBullet's forward-kinematics pass, which moves the physics' next results).
    import gymnasium as gym

    from surrol_data.envs import env_id

    env = gym.make(env_id("NeedlePick"))
    env.reset(seed=int(row["seed"]))
    for action, observation in zip(traj.action, traj.observation[1:], strict=True):
        assert np.array_equal(env.step(action)[0]["observation"], observation)
    env.close()


def test_keyboard_keys_of_the_window_drive_the_tool(tmp_path, capsys):
    from surrol_data.gui.app import TrainingApp
    from surrol_data.gui.keys import WindowKeys

    app = TrainingApp(out=tmp_path, offscreen=True, size=(480, 270))
    send = app.base.messenger.send
    # The mouse wheel over the task list scrolls it: the event Panda3D's GUI sends for a wheel turn over a card.
    from panda3d.core import MouseButton, PGButton

    from surrol_data.gui.app import WHEEL_DOWN, WHEEL_UP

    assert WHEEL_DOWN == PGButton.get_press_prefix() + MouseButton.wheel_down().get_name() + "-"
    assert WHEEL_UP == PGButton.get_press_prefix() + MouseButton.wheel_up().get_name() + "-"
    bar = app.panel.verticalScroll
    top = bar.getValue()
    send(WHEEL_DOWN + app.cards["PegTransfer"].guiId, [None])
    send(WHEEL_DOWN + app.cards["PegTransfer"].guiId, [None])
    scrolled = bar.getValue()
    send(WHEEL_UP + app.cards["NeedlePick"].guiId, [None])
    assert scrolled > top and top < bar.getValue() < scrolled

    app.choose_task("NeedleReach")
    app.set_session("keyboard", "novice", "k1")

    def hand(task):
        # The events a real key press makes in the window: hold `d` (tool +x) for a while, then Esc.
        if app.hud.steps == 1 and app.hud.attempt == 1:
            send(WindowKeys.DOWN_EVENT, ["d"])
        elif app.hud.steps == 8:
            send(WindowKeys.UP_EVENT, ["d"])
            send(WindowKeys.DOWN_EVENT, ["escape"])
        return task.cont

    # Panda3D's task manager is one per process: a "hand" task left by an earlier test in this process
    # would press its own keys in this window
    app.base.taskMgr.remove("hand")
    app.base.taskMgr.add(hand, "hand")
    app.exit_after_session = True   # Esc ends the session; the window would stay open for the next one
    app.play()
    app.run()
    assert app.last_error is None and app.last_result.ended_by == "operator"
    assert app.hud.path_m > 0.002   # the held key moved the tool millimetres (untouched, it stays still)
    # The keys are on screen (the HUD); the terminal that started the window gets no list of them.
    assert "keys:" not in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (Debian package `xvfb`) for an X display")
def test_gui_on_an_x_display_through_the_cli(tmp_path):
    display = ":97"
    xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        env = {**os.environ, "DISPLAY": display}
        shot = tmp_path / "window.png"
        run = subprocess.run([sys.executable, "-m", "surrol_data.cli", "gui", "--task", "NeedleReach",
                              "--device", "operator", "--skill", "expert", "--autoplay", "1", "--onscreen",
                              "--out", str(tmp_path / "out"), "--screenshot", str(shot)],
                             env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stdout + run.stderr
        assert "recorded 1 episodes" in run.stdout
        assert shot.stat().st_size > 10_000
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=10)
    from surrol_data.datasets.validate import validate_dataset

    assert validate_dataset(tmp_path / "out" / "NeedleReach") == []


def test_hud_counts_time_path_and_flags_per_attempt():
    from surrol_data.envs.units import CONTROL_PERIOD_S
    from surrol_data.gui.hud import Hud

    hud = Hud(task="NeedlePick")
    tips = [(0.0, 0.0, 0.0), (0.03, 0.0, 0.0), (0.03, 0.04, 0.0)]
    for step, tip in enumerate(tips, start=1):
        hud.update(step, {"tip_position": [tip], "is_success": step == 3}, {"jaw_button": step >= 2, "clutch": False})
    assert hud.attempt == 1 and hud.steps == 3
    assert hud.path_m == pytest.approx(0.07)
    assert hud.time_s == pytest.approx(3 * CONTROL_PERIOD_S)
    assert hud.success and hud.jaw_closed == [True] and hud.clutch == [False]   # per arm
    hud.update(1, {"tip_position": [(1.0, 1.0, 1.0)], "is_success": False}, {})   # a new attempt starts afresh
    assert hud.attempt == 2 and hud.path_m == 0.0 and not hud.success


@pytest.mark.parametrize("args, message", [
    (["--task", "NeedleJuggle"], "unknown task"),
    (["--device", "joystick"], "--device must be one of"),
    (["--skill", "wizard"], "--skill must be one of"),
    (["--autoplay", "1"], "--autoplay needs --task"),
])
def test_gui_cli_refuses_bad_options(args, message):
    from typer.testing import CliRunner

    from surrol_data.cli import app

    result = CliRunner().invoke(app, ["gui", *args])
    assert result.exit_code == 2
    assert message in " ".join(result.output.split())


def test_a_slow_step_does_not_stop_the_window(tmp_path, monkeypatch):
    """The window's loop keeps drawing while a step is slow: stepping runs off the window's thread (on the
    window's thread, the loop could not draw one frame until the step returned, and this test would time out)."""
    from surrol_data.collect.operator.operator import SimulatedOperator
    from surrol_data.gui.app import TrainingApp

    app = TrainingApp(out=tmp_path, offscreen=True, size=(320, 180))
    app.choose_task("NeedleReach")
    app.set_session("operator", "expert", "slow")
    drawn_during_read = []
    read = SimulatedOperator.read

    def slow_read(self):
        if not drawn_during_read:   # the first step: held until the window has drawn five more frames
            start, deadline = len(app.frame_times), time.monotonic() + 120
            while len(app.frame_times) < start + 5 and time.monotonic() < deadline:
                time.sleep(0.01)
            drawn_during_read.append(len(app.frame_times) - start)
        return read(self)

    give_up = time.monotonic() + 300   # a session that ended early must fail the asserts below, not hang

    def leave(task):
        if app.hud.steps >= 2 or app.last_error is not None or time.monotonic() > give_up:
            app.request_exit()
        return task.cont

    monkeypatch.setattr(SimulatedOperator, "read", slow_read)
    app.base.taskMgr.remove("leave")
    app.base.taskMgr.add(leave, "leave")
    app.play()
    app.run()
    assert app.last_error is None
    assert drawn_during_read and drawn_during_read[0] >= 5
    assert app.steps_drawn >= 2   # and every step was drawn once it was taken


def test_an_attempt_out_of_time_is_kept_only_when_saved(tmp_path):
    """Nobody touches the keys: each attempt runs out of time and waits; f drops the first, Enter keeps the
    second. The HUD shows the time limit and the keys."""
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.gui.app import TrainingApp
    from surrol_data.gui.keys import WindowKeys

    app = TrainingApp(out=tmp_path, offscreen=True, size=(480, 270))
    app.choose_task("NeedleReach")
    app.set_session("keyboard", "novice", "k2")
    app.max_steps = 4
    send = app.base.messenger.send
    waited, shown = {1: 0, 2: 0}, []

    def key(name):
        send(WindowKeys.DOWN_EVENT, [name])
        send(WindowKeys.UP_EVENT, [name])

    def hand(task):
        hud = app.hud
        if hud.timed_out and hud.attempt in waited and waited[hud.attempt] < 10:
            waited[hud.attempt] += 1   # frames drawn while the attempt waits for a decision, up to the key
            if waited[hud.attempt] == 10:
                shown.append((app.hud_text.getText(), app.keys_text.getText()))
                key("f" if hud.attempt == 1 else "enter")
        elif hud.attempt == 3 and hud.steps == 1:
            key("escape")
        return task.cont

    app.base.taskMgr.remove("hand")
    app.base.taskMgr.add(hand, "hand")
    app.exit_after_session = True
    app.play()
    app.run()
    assert app.last_error is None
    result = app.last_result
    assert (result.discarded, result.kept, result.ended_by) == (1, 1, "operator")
    assert waited == {1: 10, 2: 10}   # each out-of-time attempt waited for its key, ten frames and more
    reader = DatasetReader(tmp_path / "NeedleReach")
    assert len(reader) == 1 and int(reader.episodes.iloc[0]["seed"]) == 1   # the kept one is the second attempt
    hud_text, keys_text = shown[0]
    assert "time   0.8 / 0.8 s" in hud_text and "TIME UP" in hud_text
    assert "w a s d up left down right" in keys_text and "Enter save" in keys_text


def test_two_arm_sessions_report_each_arms_jaw_and_clutch():
    """BiPegTransfer with both hands on the keyboard: the left hand holds its jaw key, the right its clutch key;
    the session reports each arm's buttons and the HUD shows both arms."""
    import tempfile

    from surrol_data.collect.devices.keyboard import KeyboardDevice, KeyEvent, KeyTracker
    from surrol_data.collect.haptic_source import collect_haptic
    from surrol_data.gui.hud import Hud

    class Held:   # a key source whose keys are held down from the start
        def __init__(self, keys):
            self.events = [KeyEvent(k, True) for k in keys]

        def start(self):
            pass

        def stop(self):
            pass

        def poll(self):
            events, self.events = self.events, []
            return events

    tracker = KeyTracker(Held(["c", "b"]))   # c: the left hand's jaw; b: the right hand's clutch
    flags = []
    with tempfile.TemporaryDirectory() as out:
        collect_haptic("BiPegTransfer", 1, out + "/ds", device=[KeyboardDevice(tracker, "left"),
                                                                KeyboardDevice(tracker, "right")],
                       max_steps=2, keep_failures=True, progress=False, realtime=False,
                       on_step=lambda env, step, obs, info, f: flags.append((info, f)))
    info, last = flags[-1]
    assert last["jaw_buttons"] == [True, False] and last["clutches"] == [False, True]
    hud = Hud(task="BiPegTransfer", arms=2)
    hud.update(1, info, last)
    assert "PSM1 jaw closed  clutch off   PSM2 jaw open  clutch ON" in hud.lines()


def test_hud_shows_the_keys_and_the_time_limit():
    from surrol_data.gui.hud import Hud

    hud = Hud(task="BiPegTransfer", device="keyboard", arms=2, limit_steps=100)
    assert hud.lines() == ["BiPegTransfer   keyboard", "press play to start"]   # before the first attempt
    hud.start_attempt()
    keys = hud.key_lines()
    assert keys[0].startswith("left hand: w a s d up left down right   q e toward away   z x roll   c jaw")
    assert keys[1].startswith("right hand: i j k l up left down right   u o toward away")
    assert "Enter save" in keys[-1] and "Esc end the session" in keys[-1]
    assert "/ 20 s" in hud.lines()[1]   # 100 steps of 0.2 s
    assert Hud(device="operator", skill="novice").lines()[0].endswith("simulated operator (novice)")
    assert Hud(device="touch").key_lines()[0].startswith("Enter save")   # no keyboard keys for a Touch


@pytest.mark.parametrize("task, period", [("ECMReach", 0.1), ("NeedleReach", 0.2)])
def test_a_paced_session_steps_at_the_tasks_control_period(tmp_path, monkeypatch, task, period):
    """As the GUI runs a session (realtime): an ECM task steps every 0.1 s, an arm task every 0.2 s. Each step
    waits until start + k × period; the wake-up times asked of the (real) sleep show the pace whatever the
    machine's load (a loaded machine skips waits, it does not move them)."""
    from surrol_data.collect import haptic_source
    from surrol_data.collect.haptic_source import collect_haptic, control_period_s

    wake_ups = []
    sleep = time.sleep

    def timed_sleep(seconds):
        if sys._getframe(1).f_code.co_name == "_attempt":   # the pacing wait, not another thread's sleep
            wake_ups.append(time.monotonic() + seconds)
        sleep(seconds)

    monkeypatch.setattr(haptic_source.time, "sleep", timed_sleep)
    collect_haptic(task, 1, tmp_path / "ds", device="operator", skill="expert", operator_id="pace", max_steps=6,
                   keep_failures=True, progress=False, realtime=True)
    monkeypatch.undo()
    assert len(wake_ups) >= 3, "the paced session never waited"
    steps = np.diff(wake_ups) / period
    assert np.allclose(steps, np.round(steps), atol=0.1) and np.round(steps).min() == 1, \
        f"wake-ups {np.diff(wake_ups)} s apart, not whole {period} s steps"
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401
    from surrol_data.envs import env_id

    env = gym.make(env_id(task))
    assert control_period_s(env) == period   # what the GUI's HUD counts time in
    env.close()


def relative_luminance(rgb: np.ndarray) -> np.ndarray:
    """WCAG 2 relative luminance of sRGB pixels (0–255)."""
    c = rgb.astype(np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return linear @ np.array([0.2126, 0.7152, 0.0722])


def window_pixels(app) -> np.ndarray:
    """The window as drawn now (rows top to bottom, RGB)."""
    app.base.graphicsEngine.render_frame()
    tex = app.base.win.get_screenshot()
    w, h = tex.get_x_size(), tex.get_y_size()
    return np.frombuffer(tex.get_ram_image_as("RGB"), np.uint8).reshape(h, w, 3)[::-1]


def view_pixels(app, hud_margins: bool = False) -> np.ndarray:
    """The window's endoscope view (``hud_margins``: less its top and foot, where the HUD plates sit)."""
    from surrol_data.gui.app import CONTROLS_FRACTION, PANEL_FRACTION

    shot = window_pixels(app)
    h, w = shot.shape[:2]
    top, foot = (int(0.3 * h), int(0.15 * h)) if hud_margins else (0, 0)
    return shot[top:int((1 - CONTROLS_FRACTION) * h) - foot, int(PANEL_FRACTION * w) + 2:w]


def test_the_view_is_drawn_when_the_scene_changes_and_shown_again_between(tmp_path):
    """The endoscope view is shaded only in a frame after the scene changed (on llvmpipe it is most of a frame's
    CPU); the frames between show the same image, and a moved tool shows in the next frame."""
    from surrol_data.gui.app import TrainingApp

    app = TrainingApp(out=tmp_path, offscreen=True, size=(640, 400))
    try:
        app.choose_task("NeedlePick")
        for _ in range(3):
            app.frame()
        assert not app._view_buffer.is_active() and not app._stage.light.shadow.is_active()
        still = view_pixels(app).copy()
        for _ in range(2):
            app.frame()
        assert np.array_equal(view_pixels(app), still), "a frame between changes did not show the same view"
        env = app._preview_env
        action = np.zeros(env.action_space.shape, np.float32)
        action[2] = 1.0   # the tool moves (down, towards the pad)
        for _ in range(6):
            env.step(action)
        app._sync_scene()
        app.frame()
        moved = view_pixels(app)
        changed = (np.abs(moved.astype(int) - still).max(axis=2) > 30).mean()
        assert changed > 0.002, f"the moved tool did not show ({changed:.2%} of the view changed)"
    finally:
        app.close()


def text_contrast(app, text) -> float:
    """WCAG contrast of an OnscreenText's drawn text (its brightest pixels) against what surrounds the letters in
    its box (the box's median pixel: letters cover a minority of it)."""
    shot = window_pixels(app)
    h, w = shot.shape[:2]
    lo, hi = text.get_tight_bounds(app.base.aspect2d)
    aspect = w / h
    cols = [int(round((x / aspect + 1) / 2 * w)) for x in (lo[0], hi[0])]
    rows = [int(round((1 - z) / 2 * h)) for z in (hi[2], lo[2])]
    box = relative_luminance(shot[rows[0]:rows[1], cols[0]:cols[1]].reshape(-1, 3))
    assert box.size > 500, f"the text's box is {box.size} pixels: nothing drawn?"
    letters, around = np.percentile(box, 99.5), np.median(box)
    return (max(letters, around) + 0.05) / (min(letters, around) + 0.05)


def test_hud_text_reads_on_any_background(tmp_path):
    """The HUD and the key line at the view's foot stay readable (WCAG AA, 4.5:1) over the task's lit floor and
    over a white view (the worst background light text can have)."""
    from surrol_data.gui.app import TrainingApp

    app = TrainingApp(out=tmp_path, offscreen=True)
    try:
        app.choose_task("NeedleReach")
        app.set_session("keyboard", "novice", "c1")
        app.frame()
        assert app.keys_text.getText().startswith("w a s d")
        for background in ("scene", "white"):
            if background == "white":   # the view is drawn into its own buffer: that is what turns white
                app.base.render.hide()
                app.base.set_background_color(1, 1, 1, 1)
                app._view_buffer.set_clear_color((1, 1, 1, 1))
                app._redraw_view()
                app.frame()
                assert view_pixels(app, hud_margins=True).min() == 255, "the view did not turn white"
            for name, text in (("HUD", app.hud_text), ("key line", app.keys_text)):
                contrast = text_contrast(app, text)
                assert contrast >= 4.5, f"{name} over the {background}: contrast {contrast:.1f}:1 (< 4.5:1)"
    finally:
        app.close()

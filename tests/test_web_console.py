"""The web console (``surrol-data serve``): the page's messages are checked, the page's devices map as the keyboard and
gamepad do, and in a real headless Chromium: an operator's keys move the tool the right way in the streamed view, the
episode saved is in the dataset with its provenance, two browsers record into one dataset at once, a tab closed
mid-episode and a server killed lose nothing saved, and a connection without the token is refused."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from headless_chromium import PACKAGE, Chromium, chromium

VIEW = "320x240"   # the tests' view: a quarter of the default's pixels to draw on a loaded CPU


# ---------------------------------------------------------------------- without a browser
def test_page_messages_are_checked_before_they_reach_a_session():
    from surrol_data.web.server import Refused, _checked, _hello, _parse

    tasks = ["NeedlePick"]
    assert _hello({"type": "hello", "operator": "res.07", "skill": "novice", "task": "NeedlePick"}, tasks) == \
        ("res.07", "novice", "NeedlePick")
    assert _checked({"type": "input", "seq": 3, "keys": ["d"]}, tasks) == [("input", {"seq": 3, "keys": ["d"]})]
    assert _checked({"type": "command", "name": "save"}, tasks) == [("press", "enter")]
    assert _checked({"type": "command", "name": "play", "device": "gamepad"}, tasks) == [("play", "gamepad")]
    refused = [
        ("hello", {"type": "hello", "operator": "../../etc", "skill": "novice", "task": "NeedlePick"}),
        ("hello", {"type": "hello", "operator": "a", "skill": "god", "task": "NeedlePick"}),
        ("hello", {"type": "hello", "operator": "a", "skill": "novice", "task": "../NeedlePick"}),
        ("check", {"type": "task", "name": "/etc/passwd"}),
        ("check", {"type": "command", "name": "rm -rf"}),
        ("check", {"type": "command", "name": "play", "device": "touch"}),
        ("check", {"type": "input", "seq": -1, "keys": []}),
        ("check", {"type": "input", "seq": 1, "keys": ["a"] * 17}),
        ("check", {"type": "input", "seq": 1, "axes": [float("nan")]}),
        ("check", {"type": "input", "seq": 1, "buttons": [0.0] * 33}),
        ("check", {"type": "latency", "ms": "fast"}),
        ("check", {"type": "eval", "code": "1"}),
    ]
    for kind, message in refused:
        with pytest.raises(Refused):
            _hello(message, tasks) if kind == "hello" else _checked(message, tasks)
    for text in ("not json", "[1, 2]", '{"no": "type"}'):
        with pytest.raises(Refused):
            _parse(text)


def test_page_keys_and_gamepad_go_through_the_keyboard_and_gamepad_devices():
    from surrol_data.collect.devices.browser import (BrowserGamepadDevice, BrowserInput, BrowserKeyboardDevice,
                                                     BrowserKeys)
    from surrol_data.collect.devices.keyboard import KeyTracker

    page = BrowserInput()
    tracker = KeyTracker(BrowserKeys(page))
    keyboard = BrowserKeyboardDevice(page, tracker, "left")
    keyboard.connect()
    start = keyboard.read().position_mm
    page.apply({"seq": 1, "keys": ["d", "w", "rm"]})   # right and up (device x, y); an unknown name is dropped
    moved = keyboard.read().position_mm - start
    assert moved[0] > 0 and moved[1] > 0 and moved[2] == 0
    page.apply({"seq": 2, "keys": []})
    held = keyboard.read().position_mm
    assert np.array_equal(keyboard.read().position_mm, held)   # released: the stylus stays
    page.press("r")
    page.press("rm -rf")   # not a session key: dropped
    tracker.update()
    pressed = tracker.pop_pressed()
    assert pressed[-1] == "r" and "rm -rf" not in pressed
    page.add_latency([120.0, 80.0, -5.0, 1e9])   # impossible values are not kept
    stats = keyboard.settings()
    assert keyboard.name == "browser-keyboard" and stats["latency_ms"]["samples"] == 2
    assert stats["latency_ms"]["median"] == 100.0 and stats["input_messages"] == 2 and stats["layout"] == "left"

    pad = BrowserGamepadDevice(page)
    pad.connect()
    start = pad.read().position_mm
    # The Gamepad API's standard mapping: left stick right (axis 0), right stick up (axis 3 < 0), A held (jaw).
    page.apply({"seq": 3, "axes": [1.0, 0.0, 0.0, -1.0, 7.0], "buttons": [1.0]})
    frame = pad.read()
    assert frame.position_mm[0] > start[0] and frame.position_mm[1] > start[1] and frame.buttons & 1
    assert pad.name == "browser-gamepad" and pad.settings()["input_messages"] == 3


def test_serve_refuses_bad_arguments_in_one_line():
    from surrol_data.cli import app

    runner = CliRunner()
    for args, words in ((["--task", "NoSuchTask"], "unknown task"), (["--view-size", "5000x10"], "--view-size"),
                        (["--renderer", "vulkan"], "--renderer"), (["--token", "short"], "--token")):
        result = runner.invoke(app, ["serve", "--out", "unused", *args])
        assert result.exit_code != 0 and words in result.output and "Traceback" not in result.output, result.output


def test_a_session_streams_three_views_a_step_each_a_state_the_episode_passes_through_and_leaves_it_as_it_is():
    """One browser's process, driven over its pipe as the server drives it, paced as a person operates: while the
    operator holds a key, every arm step streams its end view and (where the machine draws them in time) the views a
    third and two thirds into it, each the image of that physics substep's state, in order; and the saved episode is
    what its actions give without any view drawn."""
    import io
    import multiprocessing

    import gymnasium as gym
    from PIL import Image

    from surrol_data.envs import env_id
    from surrol_data.render.env_view import EnvEndoscope
    from surrol_data.render.panda_camera import PandaEndoscopeCamera
    from surrol_data.web.worker import (JPEG_QUALITY, MID_STEP_VIEWS, STREAM_MULTISAMPLES, STREAM_SHADOW_MAP,
                                        worker_main)

    size, seed = (96, 72), 5
    ctx = multiprocessing.get_context("spawn")
    ours, theirs = ctx.Pipe()
    worker = ctx.Process(target=worker_main, args=(theirs, "NeedlePick", "op.1", "novice", seed, size, "panda3d", True),
                         daemon=True)
    worker.start()
    try:
        def receive(kind: str) -> tuple:
            while True:
                assert ours.poll(120), f"no {kind!r} from the worker"
                message = ours.recv()
                if message[0] == kind:
                    return message
                assert message[0] in ("ready", "task", "frame", "status"), message

        receive("task")
        ours.send(("play", "keyboard"))
        receive("status")
        ours.send(("input", {"seq": 1, "keys": ["a", "s"]}))   # left and toward the operator: the tool moves
        views = []   # (the HUD's step: the last finished one, the view)
        while len(views) < 3 * 7:
            _, header, view = receive("frame")
            views.append((header["hud"]["step"], view))
        ours.send(("press", "enter"))
        while True:   # the views streamed before the saved episode are all of it
            assert ours.poll(120)
            message = ours.recv()
            if message[0] == "frame":
                views.append((message[1]["hud"]["step"], message[2]))
            elif message[0] == "episode":
                record = message[1]
                break
        ours.send(("recorded", 0))
        ours.send(("quit",))
    finally:
        worker.join(30)
        if worker.is_alive():
            worker.kill()
    traj = record["traj"]
    assert record["provenance"]["seed"] == seed

    # The episode again, from its actions, with no view drawn: the same, to the bit.
    env = gym.make(env_id("NeedlePick"), render_mode="rgb_array")
    env.reset(seed=seed)
    for action, observation in zip(traj.action, traj.observation[1:], strict=True):
        obs = env.step(action)[0]
        assert np.array_equal(obs["observation"], observation)

    # And once more, drawing every physics substep's state as the worker draws it (without a forward-kinematics pass):
    # each streamed view is one of them, in order: the step's end view, and the views sent while it ran (carrying the
    # step before's HUD) those a third and two thirds into it.
    env.reset(seed=seed)
    endoscope = EnvEndoscope(env)
    camera = PandaEndoscopeCamera(env.unwrapped.client, size, endoscope.scene_scale, multisamples=STREAM_MULTISAMPLES,
                                  shadow_map_size=STREAM_SHADOW_MAP)

    def jpeg() -> bytes:
        buffer = io.BytesIO()
        Image.fromarray(camera.render(endoscope.pose(), forward_kinematics=False).rgb).save(buffer, "JPEG",
                                                                                           quality=JPEG_QUALITY)
        return buffer.getvalue()

    substeps: list[bytes] = []
    env.unwrapped.substep_hook = lambda u: substeps.append(jpeg())
    at, whole, moving = 0, 0, 0
    for step, action in enumerate(traj.action, start=1):
        substeps.clear()
        env.step(action)
        n = len(substeps)
        mids = []
        while views[at][0] == step - 1:   # sent while this step ran
            mids.append(views[at][1])
            at += 1
        assert views[at][0] == step and views[at][1] == substeps[-1], step   # its end view
        thirds = [substeps[n // 3 - 1], substeps[2 * n // 3 - 1]]
        assert all(m in thirds for m in mids) and [thirds.index(m) for m in mids] == sorted(
            thirds.index(m) for m in mids), step
        shown = [*mids, views[at][1]]
        at += 1
        whole += len(mids) == 2
        moving += len(mids) == 2 and len(set(shown)) == 3   # the tool moved between them
    assert at == len(views) and whole >= 1 and moving >= 1, (whole, moving)
    camera.close()
    env.close()


def test_a_paced_session_sends_views_a_third_of_a_step_apart_and_leaves_late_ones_out():
    """The worker's pacing on a clock of its own: views at a third, two thirds and the end of each 0.2 s step, a third
    of a step apart; a view that would be late is left out, a step that began late has only its end view (sent at
    once), and the robot keeps its pace."""
    from types import SimpleNamespace

    import surrol_data.web.worker as worker_module
    from surrol_data.web.worker import SessionWorker

    clock = SimpleNamespace(now=100.0)
    worker_module.time = SimpleNamespace(monotonic=lambda: clock.now, sleep=lambda s: setattr(clock, "now", clock.now + s),
                                         time=lambda: clock.now)
    try:
        sent: list[float] = []
        worker = SessionWorker(conn=None, task="NeedlePick", operator_id="op", skill="novice", seed=0, size=(64, 48),
                               renderer="tiny", realtime=True)
        worker.hud.period_s = 0.2
        worker.send_frame = lambda env: sent.append(round(clock.now - 100.0, 4))
        client = SimpleNamespace(getPhysicsEngineParameters=lambda: {"fixedTimeStep": 0.2 / 12})
        env = SimpleNamespace(unwrapped=SimpleNamespace(substep_hook=None, client=client), spec=None)
        worker._on_reset(env, None, {})
        assert env.unwrapped.substep_hook == worker._substep

        def step(start: float, draw_s: float = 0.0) -> list[float]:
            """One step starting at ``start`` (s after the clock's origin) whose views each take ``draw_s``."""
            clock.now = max(clock.now, 100.0 + start)
            del sent[:]
            worker.send_frame = lambda env: (sent.append(round(clock.now - 100.0, 4)),
                                             setattr(clock, "now", clock.now + draw_s))
            for _ in range(12):
                env.unwrapped.substep_hook(env.unwrapped)
            worker._on_step(env, 1, None, {"tip_position": [0.5, 0.0, 0.7], "is_success": False}, {})
            return list(sent)

        third = 0.2 / 3
        assert step(0.0) == [0.0, round(third, 4), round(2 * third, 4)]   # on time: three views, a third apart
        assert step(0.2) == [0.2, round(0.2 + third, 4), round(0.2 + 2 * third, 4)]
        # Views that take 0.12 s: by the time the first is drawn, the second's has passed by more than half a third.
        assert step(0.4, draw_s=0.12) == [0.4, round(0.4 + 2 * third, 4)]
        # So the next step begins late (at 0.6533 instead of 0.6): only its end view, at once.
        assert step(0.6, draw_s=0.12) == [round(0.4 + 2 * third + 0.12, 4)]
        assert step(0.8) == [0.8, round(0.8 + third, 4), round(0.8 + 2 * third, 4)]   # back on time
    finally:
        worker_module.time = time


# ---------------------------------------------------------------------- in Chromium
needs_chromium = pytest.mark.skipif(chromium() is None, reason=f"needs headless Chromium: apt-get install {PACKAGE}")


@contextmanager
def console_server(out: Path, *tasks: str):
    """``surrol-data serve`` on a free port; yields (address with the token, the log lines so far)."""
    command = [str(Path(sys.executable).parent / "surrol-data"), "serve", "--out", str(out), "--port", "0",
               "--view-size", VIEW, *[a for t in tasks for a in ("--task", t)]]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    url = None
    for line in proc.stdout:
        lines.append(line)
        found = re.search(r"open (http://\S+)", line)
        if found:
            url = found.group(1)
            break
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    assert url, "".join(lines)
    try:
        yield url, lines, proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)   # a graceful stop: the writer finalizes the datasets
            try:
                proc.wait(120)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def enter_operator(page, url: str, operator: str, skill: str) -> None:
    page.goto(url)
    page.wait_for("document.getElementById('who')?.open")
    page.js("document.getElementById('who-id').focus()")
    page.type_text(operator)
    page.js(f"document.getElementById('who-skill-select').value = '{skill}'")
    page.tap("Enter")
    page.wait_for("window.consoleStats.frames > 0 && !document.getElementById('play').disabled")


def hold(page, key: str, steps: int) -> None:
    """Hold ``key`` until the session has stepped ``steps`` times with it (the HUD's step count says so)."""
    page.key(key, True)
    pressed = page.js("window.consoleStats.sent")
    page.wait_for(f"window.consoleStats.lastAck >= {pressed}")   # a frame stepped with the key held
    end_of_step(page)                                             # that step's end
    first = page.js("window.consoleStats.hud.step")
    page.wait_for(f"window.consoleStats.hud.step >= {first + steps - 1}")
    page.key(key, False)
    released = page.js("window.consoleStats.sent")
    page.wait_for(f"window.consoleStats.lastAck >= {released}")   # a view stepped after the release
    end_of_step(page)


def end_of_step(page) -> None:
    """Wait for the view at the end of the step in progress (views inside a step carry the last finished step's HUD)."""
    step = page.js("window.consoleStats.hud.step")
    page.wait_for(f"window.consoleStats.hud.step > {step}")


def hold_pad(page, axis: int, value: float, steps: int) -> None:
    """Hold the page's gamepad stick ``axis`` at ``value`` for ``steps`` session steps (as :func:`hold`)."""
    for held in (True, False):
        before = page.js("window.consoleStats.sent")
        page.js(f"window.fakePad.axes[{axis}] = {value if held else 0}")   # the page polls it every frame
        page.wait_for(f"window.consoleStats.sent > {before} && window.consoleStats.lastAck >= window.consoleStats.sent")
        if held:
            end_of_step(page)
            first = page.js("window.consoleStats.hud.step")
            page.wait_for(f"window.consoleStats.hud.step >= {first + steps - 1}")
    end_of_step(page)


def play(page) -> None:
    page.js("document.getElementById('play').click()")
    page.wait_for("window.consoleStats.hud && window.consoleStats.hud.playing && window.consoleStats.hud.step > 0")


def save(page, episode_text: str = "saved episode") -> None:
    page.tap("Enter")
    page.wait_for(f"window.consoleStats.status.some(s => s.startsWith('{episode_text}'))", timeout=180)


def tool_centroids(frames: list[np.ndarray]) -> list[np.ndarray]:
    """Where the tool is in each view: the pixels that differ from the views' per-pixel median (the scene without
    the tool, where it moved far enough between views), their centroid (x, y)."""
    stack = np.stack([f.astype(np.int16) for f in frames])
    background = np.median(stack, axis=0)
    centroids = []
    for f in stack:
        mask = np.abs(f - background).sum(axis=2) > 60
        ys, xs = np.nonzero(mask)
        assert xs.size > 20, "no tool in the view"
        centroids.append(np.array([xs.mean(), ys.mean()]))
    return centroids


def episodes(root: Path):
    from surrol_data.datasets.reader import DatasetReader

    return DatasetReader(root).episodes


def refused_without_the_token(page, url: str) -> None:
    """No token, no session: the page's own WebSocket without it (or with a wrong one) never opens, the task list
    is refused."""
    page.goto(url.split("?")[0])
    # On a loaded machine the page's first fetches after the server and the browser start failed with no response
    # at all for a few seconds (then every one had its 403; cause not found): wait for an answer, then check it.
    assert page.wait_for("fetch('/api/tasks').then(r => r.status).catch(() => 0)") == 403
    for query in ("", "?token=wrong"):
        assert page.js(f"new Promise(done => {{ const ws = new WebSocket(`ws://${{location.host}}/ws{query}`);"
                       "ws.onopen = () => done('opened'); ws.onclose = () => done('refused'); })") == "refused"


@pytest.mark.browser
@needs_chromium
def test_in_chromium_a_page_without_the_token_gets_nothing_and_the_operator_is_asked_once(tmp_path):
    with console_server(tmp_path / "class", "NeedleReach", "NeedlePick") as (url, log, _), Chromium() as browser:
        page = browser.new_page()
        refused_without_the_token(page, url)
        page.goto(url)
        page.wait_for("document.getElementById('who')?.open")
        assert page.js("document.querySelectorAll('#tasks li').length") == 2
        assert page.js("fetch(`/api/tasks/NeedlePick.png`).then(r => r.headers.get('content-type'))") == "image/png"
        assert page.js("fetch(`/api/tasks/..%2F..%2Fpyproject.toml.png`).then(r => r.status)") == 404
        page.js("document.getElementById('who-id').value = 'not a valid id!'")
        page.tap("Enter")   # refused by the form: still asking
        assert page.js("document.getElementById('who').open and localStorage.getItem('surrol.operator') === null"
                       .replace(" and ", " && "))
        page.js("document.getElementById('who-id').value = 'resident07'")
        page.js("document.getElementById('who-form').requestSubmit()")
        page.wait_for("localStorage.getItem('surrol.operator') === 'resident07'")
        page.goto(url)   # the same browser again: not asked again
        assert page.js("document.getElementById('who').open") is False
        assert page.js("document.getElementById('who-name').textContent") == "resident07"
    assert "".join(log).count("refused a connection") == 2


@pytest.mark.browser
@pytest.mark.slow
@needs_chromium
def test_an_operator_in_chromium_moves_the_tool_and_saves_an_episode_with_provenance(tmp_path):
    out = tmp_path / "class"
    with console_server(out, "NeedleReach", "NeedlePick") as (url, log, _), Chromium() as browser:
        page = browser.new_page()
        refused_without_the_token(page, url)
        enter_operator(page, url, "resident07", "novice")
        assert page.js("document.querySelectorAll('#tasks li').length") == 2
        assert page.js("localStorage.getItem('surrol.operator')") == "resident07"
        play(page)
        hold(page, "s", 3)   # down in the image: the tool comes down into the view
        views = [page.canvas()]
        for _ in range(2):   # left in the image, twice
            hold(page, "a", 3)
            views.append(page.canvas())
        (x0, y0), (x1, _), (x2, _) = tool_centroids(views)
        width = views[0].shape[1]
        assert x0 - x1 > 0.03 * width and x1 - x2 > 0.03 * width, (x0, x1, x2)
        save(page)
        page.tap("Escape")
        page.wait_for("window.consoleStats.status.some(s => s.startsWith('session ended: 1 saved'))")
        latencies = page.js("window.consoleStats.latencies")
        assert latencies and all(0 < v < 30_000 for v in latencies)

        # The gamepad, through the browser's Gamepad API (a pad the page reads as Chromium would report one).
        page.js("window.fakePad = {id: 'test pad (STANDARD GAMEPAD)', axes: [0, 0, 0, 0], buttons: Array.from("
                "{length: 17}, () => ({pressed: false, value: 0}))}; navigator.getGamepads = () => [window.fakePad];"
                "document.getElementById('device').value = 'gamepad';"
                "document.getElementById('device').dispatchEvent(new Event('change'))")
        play(page)
        hold_pad(page, 3, 1.0, 3)   # right stick pulled down: down in the image
        views = [page.canvas()]
        for _ in range(2):
            hold_pad(page, 0, -1.0, 3)   # left stick left: left in the image
            views.append(page.canvas())
        (x0, _), (x1, _), (x2, _) = tool_centroids(views)
        assert x0 - x1 > 0.03 * width and x1 - x2 > 0.03 * width, (x0, x1, x2)
        page.js("window.fakePad.buttons[9] = {pressed: true, value: 1}")   # Start: save
        page.wait_for("window.consoleStats.status.some(s => s.startsWith('saved episode 1'))", timeout=180)
        page.js("window.fakePad.buttons[9] = {pressed: false, value: 0}")
        page.tap("Escape")
        page.wait_for("window.consoleStats.status.filter(s => s.startsWith('session ended: 1 saved')).length == 2")
    text = "".join(log)
    assert text.count("refused a connection") == 2, text
    table = episodes(out / "NeedleReach")
    assert len(table) == 2
    pad = table.iloc[1]
    assert (pad["device"], pad["operator_id"]) == ("browser-gamepad", "resident07")
    assert json.loads(pad["device_settings"])["devices"][0]["settings"]["controller"] == "test pad (STANDARD GAMEPAD)"
    row = table.iloc[0]
    assert (row["device"], row["operator_id"], row["skill"], row["source"]) == \
        ("browser-keyboard", "resident07", "novice", "haptic")
    settings = json.loads(row["device_settings"])["devices"][0]["settings"]
    assert settings["input_rate_hz"] > 0 and settings["input_messages"] >= 6
    assert settings["latency_ms"]["samples"] >= 1 and settings["latency_ms"]["median"] > 0
    assert (out / "NeedleReach" / "meta" / "device_traces").is_dir()
    assert not (out / "NeedlePick").exists()   # nothing recorded, no dataset


@pytest.mark.browser
@pytest.mark.slow
@needs_chromium
def test_two_browsers_record_into_one_dataset_and_a_closed_tab_or_a_killed_server_loses_nothing_saved(tmp_path):
    from surrol_data.datasets.guard import ensure_finished
    from surrol_data.datasets.validate import validate_dataset

    out = tmp_path / "class"
    with console_server(out, "NeedleReach") as (url, log, server), Chromium() as browser:
        pages = [browser.new_page() for _ in range(3)]
        for i, page in enumerate(pages):
            enter_operator(page, url, f"student{i}", "novice")
        for page in pages:
            play(page)
        # Both at once: each holds a key for a few steps, then saves.
        done = []
        workers = [threading.Thread(target=lambda p=p, k=k: (hold(p, k, 3), save(p), done.append(p)))
                   for p, k in ((pages[0], "s"), (pages[1], "a"))]
        for w in workers:
            w.start()
        hold(pages[2], "w", 2)
        browser.close_page(pages[2])   # mid-episode: its attempt is dropped, nothing else
        for w in workers:
            w.join(300)
        assert len(done) == 2
        deadline = time.monotonic() + 60   # the closed tab's process ends its attempt, then is gone
        while "operator student2) ended" not in "".join(log):
            assert time.monotonic() < deadline, "".join(log)
            time.sleep(0.5)
        # Killed outright (no shutdown): every episode answered "saved" survives.
        server.send_signal(signal.SIGKILL)
        server.wait(30)
    ensure_finished(out / "NeedleReach")   # what every command does first with a dataset a kill left
    problems = validate_dataset(out / "NeedleReach", check_reward=False)
    assert problems == [], problems
    table = episodes(out / "NeedleReach")
    assert sorted(table["operator_id"]) == ["student0", "student1"]
    assert set(table["device"]) == {"browser-keyboard"} and len(set(table["seed"])) == 2

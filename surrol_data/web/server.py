"""The web console's server: the page, one session process per browser, one writer (Starlette + uvicorn).

* ``GET /``, ``/static/<file>``: the page (HTML, JS, CSS shipped in the package: nothing is fetched from elsewhere);
  ``GET /api/tasks`` and ``/api/tasks/<Task>.png``: the tasks offered and their pictures.
* ``/ws?token=...``: a browser's session. Without the access token the connection is refused. The page first sends
  ``{"type": "hello", "operator": ..., "skill": ..., "task": ...}``; the server starts the browser's own process
  (:mod:`surrol_data.web.worker`) and then relays: the page's input state, the latencies it measured and its
  commands to the process; the process's frames (one JSON header then the JPEG), heads-up display and status back.
  The episodes the process keeps go to the one :class:`~surrol_data.web.writer.EpisodeWriter`.

What the page sends is checked before it goes anywhere: text messages only, at most ``MAX_MESSAGE_BYTES``, JSON of a
known type with bounded fields, at most ``MAX_MESSAGES_PER_S`` a second (a token bucket); anything else is refused
with a log line and dropped. Task names are checked against the tasks offered, so no path and no command reaches the
server from the page. A browser that closes, reloads or is cut off ends its process: the attempt in progress is
dropped, the episodes it kept are in the dataset.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import logging
import math
import multiprocessing
import re
import secrets
import threading
import time
from collections import deque
from pathlib import Path

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from surrol_data.collect.haptic_source import SKILLS
from surrol_data.web.worker import BROWSER_DEVICES, worker_main
from surrol_data.web.writer import EpisodeWriter

log = logging.getLogger("surrol_data.web")

STATIC = Path(__file__).parent / "static"
STATIC_FILES = {"app.js": "text/javascript", "style.css": "text/css"}   # all the page loads besides itself
TASK_PICTURES = Path(__file__).resolve().parents[2] / "docs" / "tasks"   # in a clone; drawn when absent
MAX_MESSAGE_BYTES = 4096
MAX_MESSAGES_PER_S = 120     # a page polls its gamepad at ~60 Hz; more is refused
MAX_SESSIONS = 16            # browsers at once (each has a process: a 2-core machine serves 2 well)
OPERATOR_ID = re.compile(r"^[\w.@+-]{1,64}$")
COMMAND_KEYS = {"redo": "r", "discard": "f", "save": "enter", "end": "esc"}
SEEDS_PER_SESSION = 10_000   # browser i of a server run starts at the dataset's next seed + i × this
QUIT_WAIT_S = 15.0           # a closed browser's process ends its attempt; then it is stopped
CSP = ("default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'; "
       "connect-src 'self'; frame-ancestors 'none'")


class Refused(ValueError):
    """A message of the page that is not accepted (the text says why)."""


class WebConsole:
    """The server's state: the tasks offered, the access token, the writer and the sessions."""

    def __init__(self, out: str | Path, tasks: list[str], token: str, size: tuple[int, int] = (640, 480),
                 renderer: str = "panda3d", realtime: bool = True, max_sessions: int = MAX_SESSIONS):
        self.out = Path(out)
        self.tasks = list(tasks)
        self.token = token
        self.size, self.renderer, self.realtime = tuple(size), renderer, realtime
        self.max_sessions = max_sessions
        self.writer = EpisodeWriter(self.out)
        self.sessions: set[BrowserSession] = set()
        self._seeds = {task: self.writer.first_seed(task) for task in self.tasks}
        self._started = 0
        self._pictures: dict[str, bytes] = {}

    def app(self) -> Starlette:
        return Starlette(routes=[Route("/", self.page), Route("/static/{name}", self.static),
                                 Route("/api/tasks", self.task_list), Route("/api/tasks/{name}.png", self.picture),
                                 WebSocketRoute("/ws", self.session)],
                         lifespan=self._lifespan)

    @contextlib.asynccontextmanager
    async def _lifespan(self, app):
        yield
        await asyncio.gather(*(s.stop() for s in list(self.sessions)), return_exceptions=True)
        await asyncio.get_running_loop().run_in_executor(None, self.writer.close)

    def next_seed(self, task: str) -> int:
        self._started += 1
        return self._seeds[task] + (self._started - 1) * SEEDS_PER_SESSION

    # ------------------------------------------------------------------ HTTP
    async def page(self, request: Request) -> Response:
        return HTMLResponse((STATIC / "index.html").read_text(), headers={"Content-Security-Policy": CSP})

    async def static(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in STATIC_FILES:
            return Response("not found", status_code=404)
        return Response((STATIC / name).read_bytes(), media_type=STATIC_FILES[name],
                        headers={"Cache-Control": "no-cache"})

    def _authorised(self, request) -> bool:
        return secrets.compare_digest(str(request.query_params.get("token", "")), self.token)

    async def task_list(self, request: Request) -> Response:
        if not self._authorised(request):
            return JSONResponse({"error": "no access token"}, status_code=403)
        return JSONResponse({"tasks": [{"name": t, "description": _description(t)} for t in self.tasks],
                             "skills": list(SKILLS), "devices": list(BROWSER_DEVICES)})

    async def picture(self, request: Request) -> Response:
        name = request.path_params["name"]
        if name not in self.tasks:
            return Response("not found", status_code=404)
        if name not in self._pictures:
            path = TASK_PICTURES / f"{name}.png"
            self._pictures[name] = (path.read_bytes() if path.is_file() else
                                    await asyncio.get_running_loop().run_in_executor(None, _draw_picture, name))
        return Response(self._pictures[name], media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    # ------------------------------------------------------------------ WebSocket
    async def session(self, ws: WebSocket) -> None:
        client = f"{ws.client.host}:{ws.client.port}" if ws.client else "?"
        if not self._authorised(ws):
            log.warning("refused a connection from %s: no valid access token", client)
            await ws.close(code=1008)
            return
        if len(self.sessions) >= self.max_sessions:
            log.warning("refused a connection from %s: %d sessions already", client, self.max_sessions)
            await ws.close(code=1013)
            return
        await ws.accept()
        try:
            hello = _parse(await asyncio.wait_for(ws.receive_text(), timeout=120))
            operator, skill, task = _hello(hello, self.tasks)
        except Refused as e:
            log.warning("refused the session of %s: %s", client, e)
            await ws.send_text(json.dumps({"type": "error", "text": str(e)}))
            await ws.close(code=1008)
            return
        except (WebSocketDisconnect, asyncio.TimeoutError, KeyError, RuntimeError):
            return
        session = BrowserSession(self, ws, client, operator, skill, task)
        self.sessions.add(session)
        try:
            await session.run()
        finally:
            self.sessions.discard(session)


class BrowserSession:
    """One page and its process: relays what each sends to the other (see the module docstring)."""

    def __init__(self, console: WebConsole, ws: WebSocket, client: str, operator: str, skill: str, task: str):
        self.console, self.ws, self.client = console, ws, client
        self.operator, self.skill, self.task = operator, skill, task
        self.loop = asyncio.get_running_loop()
        self._outbox: deque = deque()   # ("frame", header, jpeg) and ("control", message), in order
        self._wake = asyncio.Event()
        self._send_lock = threading.Lock()
        self._tokens, self._refill_at = float(MAX_MESSAGES_PER_S), time.monotonic()
        self._refused_logged_at = 0.0
        self.refused = 0
        self.frames_dropped = 0
        self._closed = False
        self.playing = False   # a session runs in the process (it has an attempt to drop cleanly)
        ctx = multiprocessing.get_context("spawn")   # a fresh interpreter: no server threads or sockets inherited
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=worker_main, name=f"surrol-web-{operator}", daemon=True,
                                   args=(child, task, operator, skill, console.next_seed(task), console.size,
                                         console.renderer, console.realtime))
        self.process.start()
        child.close()
        log.info("session of %s (operator %s, %s) started: process %d", client, operator, skill, self.process.pid)
        self._reader = threading.Thread(target=self._read_worker, name="surrol-web-reader", daemon=True)
        self._reader.start()

    # ------------------------------------------------------------------ the process's side
    def to_worker(self, *message) -> None:
        with self._send_lock:
            try:
                self.conn.send(message)
            except (BrokenPipeError, OSError):
                pass   # the process ended; the reader reports it

    def _read_worker(self) -> None:
        """The reader thread: the process's messages, to the page (frames: only the newest waits) or the writer."""
        while True:
            try:
                message = self.conn.recv()
            except Exception:   # the process ended (or died mid-message: nothing it sent then was answered)
                break
            kind = message[0]
            if kind == "frame":
                self.playing = bool(message[1]["hud"]["playing"])
            elif kind == "session_ended":
                self.playing = False
            if kind == "episode":
                self.console.writer.submit(message[1]["task"], message[1], lambda answer: self.to_worker(*answer))
                continue
            if kind == "frame":
                self.loop.call_soon_threadsafe(self._put_frame, message[1], message[2])
            else:
                self.loop.call_soon_threadsafe(self._put_control, {"type": kind, "data": message[1]})
        self.loop.call_soon_threadsafe(self._put_control, {"type": "ended"})

    def _put_frame(self, header: dict, jpeg: bytes) -> None:
        """Queue a frame; one that waits at the queue's end is replaced (a slow page sees the newest view, never a
        backlog), and nothing overtakes a control message: the page gets them in the order they were made."""
        if self._outbox and self._outbox[-1][0] == "frame":
            self._outbox.pop()
            self.frames_dropped += 1
        self._outbox.append(("frame", header, jpeg))
        self._wake.set()

    def _put_control(self, message: dict) -> None:
        self._outbox.append(("control", message))
        self._wake.set()

    async def _send_to_page(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._outbox:
                item = self._outbox.popleft()
                if item[0] == "frame":
                    await self.ws.send_text(json.dumps({"type": "frame", **item[1]}))
                    await self.ws.send_bytes(item[2])
                elif item[1]["type"] == "ended":
                    await self.ws.send_text(json.dumps({"type": "status", "data": "the session process ended"}))
                    return
                else:
                    await self.ws.send_text(json.dumps(item[1]))

    # ------------------------------------------------------------------ the page's side
    async def run(self) -> None:
        sender = asyncio.create_task(self._send_to_page())
        try:
            while True:
                message = await self.ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                try:
                    self._accept(message)
                except Refused as e:
                    self._refuse(str(e))
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            sender.cancel()
            await self.stop()

    def _accept(self, message: dict) -> None:
        now = time.monotonic()
        self._tokens = min(MAX_MESSAGES_PER_S, self._tokens + (now - self._refill_at) * MAX_MESSAGES_PER_S)
        self._refill_at = now
        if self._tokens < 1:
            raise Refused(f"more than {MAX_MESSAGES_PER_S} messages a second")
        self._tokens -= 1
        if message.get("text") is None:
            raise Refused("a binary message (the page sends JSON text only)")
        text = message["text"]
        if len(text.encode()) > MAX_MESSAGE_BYTES:
            raise Refused(f"a message of {len(text.encode())} bytes (at most {MAX_MESSAGE_BYTES})")
        for forward in _checked(_parse(text), self.console.tasks):
            self.to_worker(*forward)

    def _refuse(self, why: str) -> None:
        self.refused += 1
        now = time.monotonic()
        if now - self._refused_logged_at >= 1.0:   # one line a second at most, with the count
            log.warning("refused from %s (operator %s): %s [%d refused]", self.client, self.operator, why,
                        self.refused)
            self._refused_logged_at = now

    async def stop(self) -> None:
        """End the process: in a session it ends the attempt in progress (dropped; an episode it is handing to the
        writer is handed over first); out of one it has nothing to keep and is stopped at once."""
        if self._closed:
            return
        self._closed = True
        if self.playing:
            self.to_worker("quit")
        else:
            self.process.terminate()
        await self.loop.run_in_executor(None, self._join)
        log.info("session of %s (operator %s) ended", self.client, self.operator)

    def _join(self) -> None:
        self.process.join(QUIT_WAIT_S)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()


# ---------------------------------------------------------------------- the page's messages
def _parse(text: str) -> dict:
    try:
        message = json.loads(text)
    except (json.JSONDecodeError, TypeError):
        raise Refused("a message that is not JSON") from None
    if not isinstance(message, dict) or not isinstance(message.get("type"), str):
        raise Refused("a message without a type")
    return message


def _hello(message: dict, tasks: list[str]) -> tuple[str, str, str]:
    if message.get("type") != "hello":
        raise Refused("the first message must be hello")
    operator, skill, task = message.get("operator"), message.get("skill"), message.get("task")
    if not isinstance(operator, str) or not OPERATOR_ID.match(operator):
        raise Refused("operator id: 1 to 64 letters, digits or . _ - + @")
    if skill not in SKILLS:
        raise Refused(f"skill must be one of {', '.join(SKILLS)}")
    if task not in tasks:
        raise Refused(f"task must be one of {', '.join(tasks)}")
    return operator, skill, task


def _numbers(values, most: int, what: str) -> list[float]:
    if not isinstance(values, list) or len(values) > most:
        raise Refused(f"{what}: a list of at most {most} numbers")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
        raise Refused(f"{what}: numbers only")
    return [float(v) for v in values]


def _checked(message: dict, tasks: list[str]) -> list[tuple]:
    """What a page's message asks the process to do (see the module docstring); :class:`Refused` otherwise."""
    kind = message["type"]
    if kind == "input":
        seq = message.get("seq")
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < 2 ** 53:
            raise Refused("input: seq must be a non-negative integer")
        clean: dict = {"seq": seq}
        if "keys" in message:
            keys = message["keys"]
            if not isinstance(keys, list) or len(keys) > 16 or not all(isinstance(k, str) and len(k) <= 8 for k in keys):
                raise Refused("input: keys must be a list of at most 16 key names")
            clean["keys"] = keys
        if "axes" in message:
            clean["axes"] = _numbers(message["axes"], 8, "input axes")
        if "buttons" in message:
            clean["buttons"] = _numbers(message["buttons"], 32, "input buttons")
        if "pad" in message:
            clean["pad"] = str(message["pad"])[:80]
        return [("input", clean)]
    if kind == "latency":
        return [("latency", [v for v in _numbers(message.get("ms"), 100, "latency") if v >= 0])]
    if kind == "command":
        name = message.get("name")
        if name == "play":
            device = message.get("device")
            if device not in BROWSER_DEVICES:
                raise Refused(f"play: device must be one of {', '.join(BROWSER_DEVICES)}")
            return [("play", device)]
        if name in COMMAND_KEYS:
            return [("press", COMMAND_KEYS[name])]
        raise Refused(f"command must be play or one of {', '.join(COMMAND_KEYS)}")
    if kind == "task":
        if message.get("name") not in tasks:
            raise Refused(f"task must be one of {', '.join(tasks)}")
        return [("task", message["name"])]
    raise Refused(f"a message of unknown type {kind[:20]!r}")


def _description(task: str) -> str:
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    import surrol_data.envs  # noqa: F401  (registers the tasks)
    from surrol_data.envs import env_id
    from surrol_data.gui.app import one_line

    cls = load_env_creator(gym.spec(env_id(task)).entry_point)
    return one_line(getattr(cls, "TASK", "") or (cls.__doc__ or task).strip().splitlines()[0])


def _draw_picture(task: str, size: tuple[int, int] = (192, 144)) -> bytes:
    """A task's endoscope view after a seeded reset (TinyRenderer), where the docs' pictures are not at hand."""
    import gymnasium as gym
    from PIL import Image

    from surrol_data.envs import env_id
    from surrol_data.envs.camera import make_camera
    from surrol_data.render.env_view import EnvEndoscope

    env = gym.make(env_id(task), render_mode="rgb_array")
    try:
        env.reset(seed=0)
        view = EnvEndoscope(env)
        rgb = make_camera(view.client, size, scene_scale=view.scene_scale).render(view.pose()).rgb
    finally:
        env.close()
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, "PNG")
    return buffer.getvalue()

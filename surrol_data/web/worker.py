"""One browser's process: its env, its endoscope view, and the haptic session its operator drives.

The server starts one per connected page (:func:`worker_main`, in a process of its own, so one operator's physics
and rendering never stall another's) and talks to it over a pipe:

* server → worker: ``("input", message)`` the page's input state, ``("latency", [ms, ...])`` what the page measured,
  ``("press", key)`` a session key (play / redo / discard / save / end as on the GUI), ``("task", name)``,
  ``("play", device)``, ``("quit",)``; and the writer's answers ``("recorded", index)`` / ``("record_failed", why)``;
* worker → server: ``("ready", facts)``, ``("frame", header, jpeg)`` after every env step and, in an arm task, at
  a third and two thirds of it (:data:`MID_STEP_VIEWS`), and one preview per task, ``("status", text)``,
  ``("episode", record)`` for every kept episode (it waits for the writer's answer: the session goes on only once
  the episode is durable), ``("session_ended", summary)``.

A session is :func:`surrol_data.collect.haptic_source.collect_haptic` with the page's devices
(:mod:`surrol_data.collect.devices.browser`), the session keys from the page, and an episode sink that hands each
kept episode to the server's one writer instead of opening a recorder: the same attempt loop, pacing, mapping and
provenance as every other haptic session. The pipe closing (the server gone) ends the worker; the attempt in
progress is lost, every episode already answered ``recorded`` is on disk.
"""

from __future__ import annotations

import io
import time
import traceback
from multiprocessing.connection import Connection

import gymnasium as gym
import numpy as np

from surrol_data.collect.devices.browser import (BrowserGamepadDevice, BrowserInput, BrowserKeyboardDevice,
                                                 BrowserKeys)
from surrol_data.collect.devices.keyboard import QUIT_KEY, KeyTracker
from surrol_data.collect.haptic_source import control_period_s
from surrol_data.envs import env_id
from surrol_data.envs.names import is_ecm_action
from surrol_data.gui.hud import Hud, layout_keys

SESSION_EPISODES = 10_000   # a session records until the operator ends it
JPEG_QUALITY = 80
# Views drawn inside an arm task's step besides the one after it: 3 per 0.2 s step, 15 per second, each of the state
# the physics has reached, sent a third of a step apart (see SessionWorker._substep).
MID_STEP_VIEWS = 2
# The streamed Panda3D view: no multisampling and a 512² shadow map (the GUI's: 4× and 1024²). The JPEG's blocks soften
# edges more than the missing anti-aliasing does, and on a software rasteriser (Mesa's llvmpipe) a 640×480 view then
# costs ~70 instead of ~105 ms of CPU: enough for 15 a second on two cores beside the page's browser.
STREAM_MULTISAMPLES, STREAM_SHADOW_MAP = 0, 512
BROWSER_DEVICES = ("keyboard", "gamepad")


class PipeClosed(RuntimeError):
    """The server's end of the pipe closed: the worker ends."""


def worker_main(conn: Connection, task: str, operator_id: str, skill: str, seed: int, size: tuple[int, int],
                renderer: str, realtime: bool = True) -> None:
    """The worker process's body (see the module docstring)."""
    worker = SessionWorker(conn, task, operator_id, skill, seed, size, renderer, realtime)
    try:
        worker.run()
    except PipeClosed:
        pass
    finally:
        worker.close()


class SessionWorker:
    def __init__(self, conn: Connection, task: str, operator_id: str, skill: str, seed: int, size: tuple[int, int],
                 renderer: str, realtime: bool = True):
        self.conn = conn
        self.task, self.operator_id, self.skill = task, operator_id, skill
        self.next_seed = seed
        self.size, self.realtime = tuple(size), realtime
        self.renderer = renderer
        self.browser = BrowserInput(pump=self.pump)
        self.quitting = False
        self.in_session = False
        self._replies: list[tuple] = []
        self._requests: list[tuple] = []
        self._camera = self._camera_client = self._endoscope = None
        self._preview = None
        self.hud = Hud()
        self._step_start: float | None = None   # when the step in progress began (its first physics substep)
        self._last_start: float | None = None   # when the one before began
        self._step_sim_s = 0.0                  # simulated seconds of it so far
        self._mid_slots = 0                     # of its mid-step views, how many are sent or left out so far
        self._behind = False                    # the step began late: its mid-step views are left out

    # ------------------------------------------------------------------ the pipe
    def send(self, *message) -> None:
        try:
            self.conn.send(message)
        except (BrokenPipeError, EOFError, OSError):
            raise PipeClosed from None

    def pump(self, wait_for: tuple[str, ...] = ()) -> tuple | None:
        """Take in what the server sent; with ``wait_for``, block until a message of one of those kinds comes."""
        while True:
            try:
                if not wait_for and not self.conn.poll(0):
                    return None
                message = self.conn.recv()
            except (EOFError, OSError):
                raise PipeClosed from None
            kind = message[0]
            if kind in wait_for:
                return message
            if kind == "input":
                self.browser.apply(message[1])
            elif kind == "latency":
                self.browser.add_latency(message[1])
            elif kind == "press":
                self.browser.press(message[1])
            elif kind == "quit":
                self.quitting = True
                self.browser.press(QUIT_KEY)
            elif kind in ("task", "play"):
                if self.in_session:
                    self.send("status", "end the session first (Esc)")
                else:
                    self._requests.append(message)

    # ------------------------------------------------------------------ the loop
    def run(self) -> None:
        self.send("ready", {"renderer": self.renderer, "size": list(self.size)})
        self.show_task(self.task)
        while not self.quitting:
            if not self._requests:
                if self.conn.poll(0.05):
                    self.pump()
                continue
            kind, arg = self._requests.pop(0)
            if kind == "task":
                self.show_task(arg)
            elif kind == "play":
                self.play(arg)
                if not self.quitting:
                    self.show_task(self.task)

    def show_task(self, task: str) -> None:
        """The task's scene after a seeded reset, as the next attempt will start (a preview frame)."""
        self.task = task
        self._close_preview()
        self._preview = gym.make(env_id(task), render_mode="rgb_array")
        self._preview.reset(seed=self.next_seed)
        arms = self._arms(self._preview)
        self.hud = Hud(task=task, arms=arms, period_s=control_period_s(self._preview))
        keys = [("right hand: " if side == "right" else "left hand: " if arms > 1 else "") + layout_keys(side)
                for side in ("left", "right")[:arms]]
        self.send("task", {"task": task, "arms": arms, "keys": keys})
        self.send_frame(self._preview)

    def play(self, device: str) -> None:
        from surrol_data.collect.haptic_source import collect_haptic

        self._close_preview()
        tracker = KeyTracker(BrowserKeys(self.browser))
        env_probe = gym.make(env_id(self.task))
        arms = self._arms(env_probe)
        env_probe.close()
        if device == "gamepad":
            if arms > 1:
                self.send("status", f"{self.task} has two arms: drive it with the keyboard (one hand per arm)")
                return
            devices = [BrowserGamepadDevice(self.browser)]
        else:
            devices = [BrowserKeyboardDevice(self.browser, tracker, side) for side in ("left", "right")[:arms]]
        self.hud = Hud(task=self.task, device=devices[0].name, skill=self.skill, arms=arms, period_s=self.hud.period_s)
        self.in_session = True
        self.send("status", f"recording {self.task}: {devices[0].name}, operator {self.operator_id}")
        result = None
        try:
            result = collect_haptic(
                self.task, SESSION_EPISODES, "(web console)", device=devices, operator_id=self.operator_id,
                skill=self.skill, seed=self.next_seed, keep_failures=True, gui=False, progress=False,
                command="surrol-data serve", key_tracker=tracker, on_step=self._on_step, on_reset=self._on_reset,
                env_kwargs={"render_mode": "rgb_array"}, max_attempts=SESSION_EPISODES, realtime=self.realtime,
                timeout_needs_save=True, episode_sink=self._record)
        except RecordFailed as e:
            self.send("status", f"not saved: {e}")
        except (PipeClosed, KeyboardInterrupt):
            raise
        except Exception as e:   # the page hears why; the traceback goes to the server's log; play may start again
            traceback.print_exc()
            self.send("status", f"the session stopped: {type(e).__name__}: {e}")
        finally:
            self.in_session = False
            self._drop_camera()
        if result is not None:
            self.next_seed += result.attempts + result.discarded + 1
            self.send("session_ended", {"kept": result.kept, "attempts": result.attempts,
                                        "discarded": result.discarded, "redone": result.redone})

    # ------------------------------------------------------------------ per step
    def _on_reset(self, env, obs, info) -> None:
        """An attempt starts: its input rate and latency counted anew, its time limit on the HUD, and views between
        the steps of an arm task (an ECM task's steps come 10 a second; it has no substep hook)."""
        self.browser.start_episode()
        self.hud.limit_steps = env.spec.max_episode_steps if env.spec is not None else None
        self._last_start = None
        u = env.unwrapped
        if hasattr(u, "substep_hook") and u.substep_hook is None:
            u.substep_hook = self._substep

    def _on_step(self, env, step: int, obs, info, flags) -> None:
        self.hud.update(step, info, flags)
        if self._step_start is not None and self.realtime and not self._behind:
            # the step's last view a third of a step after its second (late, at once: the next step is due)
            self._wait_until(self._step_start + self._mid_slots * self.hud.period_s / (MID_STEP_VIEWS + 1))
        self._step_start, self._step_sim_s, self._mid_slots = None, 0.0, 0
        self.send_frame(env)

    def _substep(self, u) -> None:
        """After every physics substep of a step: once the physics has reached the next third of the step, that
        state's view. Paced as the step's input is (by the control period, from the step's start), one third of a
        step ahead of the physics: the first view of a step goes out as soon as the physics reaches it, the next a
        third of a step later, and the one after the step (``_on_step``) another third later, so the page gets a
        view every 67 ms, each a real state of the episode. Drawn without a forward-kinematics pass (which would
        change the episode's next steps: views leave the episode as a replay of its actions gives it).

        A machine that cannot draw them all in time keeps the robot's pace and leaves views out: a mid-step view
        whose time has passed by half a third of a step, and both of a step that began that late (the views of the
        one before took longer than the control period); the view after a step is always sent."""
        third = self.hud.period_s / (MID_STEP_VIEWS + 1)
        if self._step_start is None:
            now = self._step_start = time.monotonic()
            self._behind = self.realtime and self._last_start is not None and \
                now - self._last_start > self.hud.period_s + third / 2
            self._last_start = now
        self._step_sim_s += u.client.getPhysicsEngineParameters()["fixedTimeStep"]
        if self._mid_slots >= MID_STEP_VIEWS or self._step_sim_s < (self._mid_slots + 1) * third - 1e-9:
            return
        slot = self._step_start + self._mid_slots * third
        self._mid_slots += 1
        if self.realtime:
            if self._behind or time.monotonic() > slot + third / 2:
                return
            self._wait_until(slot)
        self.send_frame(u)

    @staticmethod
    def _wait_until(t: float) -> None:
        delay = t - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    def send_frame(self, env) -> None:
        from PIL import Image

        rgb = self._render(env)
        buffer = io.BytesIO()
        Image.fromarray(rgb).save(buffer, "JPEG", quality=JPEG_QUALITY)
        h = self.hud
        hud = {"attempt": h.attempt, "time_s": round(h.time_s, 2), "step": h.steps,
               "limit_s": None if h.limit_steps is None else round(h.limit_steps * h.period_s, 2),
               "path_cm": round(100 * h.path_m, 1), "success": h.success, "jaw_closed": h.jaw_closed,
               "clutch": h.clutch, "timed_out": h.timed_out, "playing": self.in_session}
        self.send("frame", {"ack": self.browser.seq, "hud": hud, "t": time.time()}, buffer.getvalue())

    def _render(self, env) -> np.ndarray:
        from surrol_data.envs.camera import make_camera
        from surrol_data.render.env_view import EnvEndoscope

        client = env.unwrapped.client
        if self._camera_client is not client:
            self._drop_camera()
            self._endoscope = EnvEndoscope(env)
            try:
                if self.renderer == "panda3d":
                    from surrol_data.render.panda_camera import PandaEndoscopeCamera

                    self._camera = PandaEndoscopeCamera(client, self.size, self._endoscope.scene_scale,
                                                        multisamples=STREAM_MULTISAMPLES,
                                                        shadow_map_size=STREAM_SHADOW_MAP)
                else:
                    self._camera = make_camera(client, self.size, scene_scale=self._endoscope.scene_scale,
                                               renderer=self.renderer)
            except (ImportError, RuntimeError) as e:   # no Panda3D or no EGL here: TinyRenderer draws everywhere
                if self.renderer == "tiny":
                    raise
                self.send("status", f"the view is drawn by TinyRenderer ({self.renderer}: {e})")
                self.renderer = "tiny"
                self._camera = make_camera(client, self.size, scene_scale=self._endoscope.scene_scale)
            self._camera_client = client
        return self._camera.render(self._endoscope.pose(), forward_kinematics=False).rgb

    # ------------------------------------------------------------------ recording (the server's writer)
    def _record(self, traj, provenance: dict, frames, meta: dict) -> int:
        self.send("episode", {"task": self.task, "traj": traj, "provenance": provenance, "frames": frames,
                              "meta": meta})
        reply = self.pump(wait_for=("recorded", "record_failed"))
        if reply[0] == "record_failed":
            raise RecordFailed(reply[1])
        self.send("status", f"saved episode {reply[1]} of {self.task}")
        return int(reply[1])

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _arms(env) -> int:
        dim = env.action_space.shape[0]
        return 1 if is_ecm_action(dim) else dim // 5

    def _drop_camera(self) -> None:
        if self._camera is not None and hasattr(self._camera, "close"):
            self._camera.close()
        self._camera = self._camera_client = self._endoscope = None

    def _close_preview(self) -> None:
        self._drop_camera()
        if self._preview is not None:
            self._preview.close()
            self._preview = None

    def close(self) -> None:
        self._close_preview()
        try:
            self.conn.close()
        except OSError:
            pass


class RecordFailed(RuntimeError):
    """The server's writer could not record an episode (its message says why)."""

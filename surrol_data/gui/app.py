"""The training window: a task panel, the live endoscope view with a heads-up display, session controls.

Layout (1280×720 by default): on the left every registered task as a card (its endoscope picture, name and
one-line description); on the right the endoscope view drawn by :mod:`surrol_data.render` with the HUD over
it; under the view the controls of ``collect --source haptic`` — device, operator id, skill — the buttons play,
redo, discard, save and exit, and a status line. Every text is fitted to its room (:mod:`~surrol_data.gui.text_fit`):
none runs past the window's edge.

Play runs a haptic session (:func:`surrol_data.collect.haptic_source.collect_haptic`, the same recorder and
provenance as the CLI) into ``<out>/<task>`` on a thread of its own, so the window never waits for the physics, the
recorder or their start-up: it draws at its own pace. The two threads meet once per env step: the session thread
waits while the window copies the step's PyBullet state into its scene (the only moment the window reads PyBullet
during a session) and handles that frame's events, then steps on. Panda3D stays on the main thread. An attempt
that runs out of time waits for the operator: save keeps it, redo / discard drop it. Redo / discard / save / exit press the session keys
(``r`` / ``f`` / ``Enter`` / ``Esc``) through the window's key source, so the keyboard and the buttons
do the same. Without a display the window is an offscreen buffer (tests, screenshots).

Given a policy (``surrol-data gui --policy``), play runs an intervention session instead (``collect --source
intervene``) into ``<out>/<task>_intervene``: the policy acts, and holding the *take over* button (or ``space``) hands
the arms to the operator's device until it is released; the HUD says who acts.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from pathlib import Path

import gymnasium as gym

import surrol_data.envs  # noqa: F401  (registers the tasks)
from surrol_data.collect.devices.keyboard import DISCARD_KEY, QUIT_KEY, REDO_KEY, SAVE_KEY, TAKEOVER_KEY
from surrol_data.collect.haptic_source import SKILLS, control_period_s
from surrol_data.envs import TASKS, env_id
from surrol_data.envs.names import is_ecm_action
from surrol_data.gui.hud import Hud
from surrol_data.gui.text_fit import fit_text
from surrol_data.render import display

# The events Panda3D's GUI items send when the mouse wheel turns over them (as DirectGuiGlobals' B1PRESS for clicks).
WHEEL_UP, WHEEL_DOWN = "press-wheel_up-", "press-wheel_down-"
# Devices offered in the panel: every device of `collect --source haptic` but replay (which needs a file).
DEVICES = ("keyboard", "operator", "touch", "gamepad", "spacemouse")
WINDOW_SIZE = (1280, 720)
PANEL_FRACTION = 0.34      # of the window's width, for the task panel
CONTROLS_FRACTION = 0.16   # of the window's height, for the controls under the view
THUMBNAIL = (192, 144)
VIEW_MULTISAMPLES = 4       # the endoscope view's anti-aliasing (the rest of the window is axis-aligned 2D)
# The HUD's backing: 72 % black keeps its text above 4.5:1 (WCAG AA) contrast even over a white background.
HUD_PLATE = (0.02, 0.02, 0.03, 0.72)
HUD_SCALE, KEYS_SCALE = 0.045, 0.035   # text sizes (window units) of the HUD and of the key lines under it
HUD_PLATE_MARGIN = (0.4, 0.4, 0.25, 0.3)   # left, right, bottom, top, in the text's line heights
EDGE_GAP = 0.02             # window units kept free between a text and the window's (or the view's) edge
MIN_TEXT_SCALE = 0.75       # a text too long for its room is drawn down to this share of its size, then cut
_IDLE_FRAME_S = 1 / 30
_WHEEL_STEP = 0.08          # of the task list's height per wheel notch
SESSION_EPISODES = 10_000   # a session records until exit unless told otherwise


class _WindowClosed(RuntimeError):
    """Raised in the session thread when the window closes while a step waits to be drawn."""


def one_line(text: str) -> str:
    """The first sentence of a task's description."""
    text = " ".join(text.split())
    end = text.find(". ")
    return text if end < 0 else text[:end + 1]


class TrainingApp:
    """The GUI; ``offscreen`` (default: when there is no display) draws into a buffer instead of a window."""

    def __init__(self, out: str | Path = "gui_sessions", offscreen: bool | None = None,
                 size: tuple[int, int] = WINDOW_SIZE, seed: int = 0, policy=None, policy_info: dict | None = None):
        display.configure()
        from panda3d.core import loadPrcFileData

        self.offscreen = (not display.has_display()) if offscreen is None else offscreen
        if not self.offscreen and not display.has_display():
            raise display.RendererUnavailable("an on-screen window needs a display (DISPLAY / WAYLAND_DISPLAY is "
                                              "unset); run with --offscreen, or under Xvfb")
        if self.offscreen:
            display.offscreen_pipe()   # fails early, naming the packages, where EGL is missing
            loadPrcFileData("surrol_data_gui", "load-display p3headlessgl\n")
        # The window itself is not multisampled: all it draws is axis-aligned 2D (panel, text, the view's card), which
        # comes out the same pixel for pixel without it, at half the CPU of a frame on llvmpipe; the views of the
        # scene (the endoscope view, the task pictures) are multisampled in their own buffers (`view_framebuffer`).
        loadPrcFileData("surrol_data_gui", f"win-size {size[0]} {size[1]}\nwindow-title surrol_data training\n"
                                           "framebuffer-multisample false\nmultisamples 0\n")
        from direct.showbase.ShowBase import ShowBase

        try:
            self.base = ShowBase(windowType="offscreen" if self.offscreen else "onscreen")
        except Exception as e:   # noqa: BLE001 - Panda3D says only "Could not open window." (a bare Exception)
            if self.offscreen:
                raise
            raise display.RendererUnavailable(
                f"could not open a window on the display {display.display_name()!r} ({e}): check that it is "
                "reachable (`xdpyinfo`), or run under a virtual display (`xvfb-run -a surrol-data gui --onscreen`, "
                "Debian package xvfb)") from None
        self.base.disable_mouse()
        self.base.set_background_color(0.03, 0.03, 0.035, 1)
        self.size = size
        self.out = Path(out)
        self.seed = seed
        self.policy, self.policy_info = policy, policy_info
        self.task: str | None = None
        self.device, self.skill, self.operator_id = "keyboard", "unknown", ""
        self.hud = Hud()
        self.exit_requested = False
        self.last_result = None
        self.last_task: str | None = None
        self.last_error: str | None = None
        self._play_requested = False
        self._session_running = False
        self._stage = None
        self._stage_client = None
        self._endoscope = None
        self._preview_env = None
        self.session_episodes = SESSION_EPISODES
        self.exit_after_session = False
        self.max_steps: int | None = None   # an attempt's time limit in steps (None: the human horizon)
        # The session thread and its hand-over of each env step to the window (see the module docstring).
        self._session_thread: threading.Thread | None = None
        self._session_outcome = None
        self._pending_step = None
        self._step_drawn = threading.Event()
        self._closing = False
        self.frame_times: deque[float] = deque(maxlen=100_000)   # monotonic time of every drawn frame
        self.steps_drawn = 0

        from surrol_data.gui.keys import WindowKeys

        self.keys = WindowKeys(self.base)
        self.base.userExit = self.request_exit   # closing the window is the exit button, not sys.exit mid-session
        self._setup_view()
        self._build_panel()
        self._build_controls()
        self._build_hud()
        # What a session imports on first play (the recorder; lerobot and torch behind it) is imported now, as the
        # window opens: an import holds the interpreter lock and would stall the window's frames after play.
        import lerobot.datasets.lerobot_dataset  # noqa: F401

        import surrol_data.datasets.recorder  # noqa: F401

    # ------------------------------------------------------------------ layout
    def _setup_view(self) -> None:
        """The endoscope view is drawn into a texture of its own and shown on a card where the view sits.

        Why: the scene changes only when the session hands over a step (5 per second for the arms), while the
        window draws up to 30 frames/s for the HUD, the clicks and the keys. On a software rasteriser (Mesa's
        llvmpipe) the shaded view is ~85 % of a frame's CPU, so it is drawn only when the scene has changed and
        the window's other frames show the same image again: what the surgeon sees is the same, pixel for pixel."""
        from panda3d.core import CardMaker, SamplerState, Texture

        from surrol_data.render.stage import endoscope_lens, view_framebuffer

        # The view's pixels, rounded as Panda3D rounds a display region's edges, so the card maps texels 1:1.
        left, bottom = round(PANEL_FRACTION * self.size[0]), round(CONTROLS_FRACTION * self.size[1])
        w, h = self.size[0] - left, self.size[1] - bottom
        self.base.camNode.set_active(False)   # the default camera would draw the scene into the whole window
        self._view_tex = Texture("endoscope_view")
        self._view_tex.set_minfilter(SamplerState.FT_nearest)
        self._view_tex.set_magfilter(SamplerState.FT_nearest)
        self._view_buffer = self.base.win.make_texture_buffer("endoscope_view", w, h, self._view_tex, False,
                                                              view_framebuffer(VIEW_MULTISAMPLES))
        self._view_buffer.set_clear_color(self.base.get_background_color())
        self._view_cam = self.base.make_camera(self._view_buffer, lens=endoscope_lens(w, h))
        card = CardMaker("endoscope_view_card")
        card.set_frame(-1 + 2 * left / self.size[0], 1, -1 + 2 * bottom / self.size[1], 1)
        self._view_card = self.base.render2d.attach_new_node(card.generate())
        self._view_card.set_texture(self._view_tex)
        self._view_card.set_bin("background", 0)   # under the HUD and every control
        self._view_frames = 0   # frames still to draw the view in (0: it shows the last drawn image)

    def _redraw_view(self, frames: int = 1) -> None:
        """Draw the view in the next ``frames`` frames (a new stage: its light's shadow buffer is made in its
        first frame and drawn from the next, so it takes two)."""
        self._view_frames = max(self._view_frames, frames)

    def _build_panel(self) -> None:
        from direct.gui.DirectGui import DGG, DirectButton, DirectFrame, DirectLabel, DirectScrolledFrame
        from panda3d.core import TextNode

        aspect = self.size[0] / self.size[1]
        width = 2 * aspect * PANEL_FRACTION
        DirectFrame(parent=self.base.a2dTopLeft, frameColor=(0.12, 0.12, 0.14, 1),
                    frameSize=(0, width, -2, 0))
        DirectLabel(parent=self.base.a2dTopLeft, text="Tasks", scale=0.06, pos=(0.04, 0, -0.08),
                    text_align=TextNode.A_left, text_fg=(1, 1, 1, 1), frameColor=(0, 0, 0, 0))
        card_h = 0.3
        self.panel = DirectScrolledFrame(parent=self.base.a2dTopLeft, pos=(0.02, 0, -0.12),
                                         frameSize=(0, width - 0.04, -1.86, 0),
                                         canvasSize=(0, width - 0.1, -card_h * len(TASKS), 0),
                                         frameColor=(0.12, 0.12, 0.14, 1), scrollBarWidth=0.04,
                                         verticalScroll_frameColor=(0.2, 0.2, 0.22, 1))
        pictures = self._task_pictures()
        self.cards = {}
        wheel_targets = [self.panel, self.panel.verticalScroll, self.panel.verticalScroll.thumb]
        for i, task in enumerate(TASKS):
            card = DirectButton(parent=self.panel.getCanvas(), frameSize=(0, width - 0.12, -card_h + 0.02, 0),
                                pos=(0, 0, -card_h * i), relief=DGG.FLAT, frameColor=(0.18, 0.18, 0.2, 1),
                                command=self.choose_task, extraArgs=[task], pressEffect=False)
            wheel_targets.append(card)
            if task in pictures:
                wheel_targets.append(DirectFrame(parent=card, image=pictures[task], image_scale=(0.16, 1, 0.12),
                                                 pos=(0.18, 0, -0.14), frameColor=(0, 0, 0, 0)))
            wheel_targets.append(DirectLabel(parent=card, text=task, scale=0.05, pos=(0.37, 0, -0.07),
                                             text_align=TextNode.A_left, text_fg=(1, 1, 1, 1), frameColor=(0, 0, 0, 0)))
            wheel_targets.append(DirectLabel(parent=card, text=one_line(self._description(task)), scale=0.034,
                                             pos=(0.37, 0, -0.13), text_align=TextNode.A_left,
                                             text_wordwrap=(width - 0.52) / 0.034, text_fg=(0.8, 0.8, 0.82, 1),
                                             frameColor=(0, 0, 0, 0)))
            self.cards[task] = card
        # The mouse wheel scrolls the list: Panda3D sends a wheel turn to the GUI item under the pointer (the
        # window's own wheel events are suppressed there), so every item of the panel listens for it.
        for item in wheel_targets:
            item.bind(WHEEL_UP, lambda _event: self.scroll_tasks(-1))
            item.bind(WHEEL_DOWN, lambda _event: self.scroll_tasks(1))

    def _build_controls(self) -> None:
        """The controls under the view, from the view's left edge: the menus and the operator field, the buttons,
        and under them the status line, which has the view's whole width. A window too narrow for the buttons
        draws the controls smaller (the node they hang from is scaled) so that they stay inside it."""
        from direct.gui.DirectGui import DirectButton, DirectEntry, DirectLabel, DirectOptionMenu
        from panda3d.core import TextNode

        aspect = self.size[0] / self.size[1]
        row1, row2, row3 = 2 * CONTROLS_FRACTION - 0.09, 0.125, 0.035   # above the window's bottom edge
        controls = self.base.aspect2d.attach_new_node("controls")
        controls.set_pos(-aspect + 2 * aspect * PANEL_FRACTION + 0.05, 0, -1)
        left = 0.0
        label = dict(scale=0.04, text_align=TextNode.A_left, text_fg=(0.85, 0.85, 0.85, 1), frameColor=(0, 0, 0, 0),
                     parent=controls)
        DirectLabel(text="device", pos=(left, 0, row1), **label)
        self.device_menu = DirectOptionMenu(items=list(DEVICES), initialitem=DEVICES.index(self.device),
                                            scale=0.045, pos=(left + 0.14, 0, row1), command=self._set_device,
                                            parent=controls, highlightColor=(0.6, 0.6, 0.65, 1))
        DirectLabel(text="operator", pos=(left + 0.58, 0, row1), **label)
        self.operator_entry = DirectEntry(initialText=self.operator_id, scale=0.045, width=8,
                                          pos=(left + 0.76, 0, row1), command=self._set_operator, parent=controls,
                                          focusInCommand=self._typing, focusInExtraArgs=[True],
                                          focusOutCommand=self._typing, focusOutExtraArgs=[False])
        DirectLabel(text="skill", pos=(left + 1.2, 0, row1), **label)
        self.skill_menu = DirectOptionMenu(items=list(SKILLS), initialitem=SKILLS.index(self.skill), scale=0.045,
                                           pos=(left + 1.3, 0, row1), command=self._set_skill, parent=controls,
                                           highlightColor=(0.6, 0.6, 0.65, 1))
        button = dict(scale=0.05, frameSize=(-2.2, 2.2, -0.6, 1.0), text_fg=(1, 1, 1, 1), parent=controls)
        self.buttons = {
            "play": DirectButton(text="play", pos=(left + 0.12, 0, row2), command=self.play,
                                 frameColor=(0.15, 0.5, 0.2, 1), **button),
            "redo": DirectButton(text="redo", pos=(left + 0.40, 0, row2), command=self.keys.press,
                                 extraArgs=[REDO_KEY], frameColor=(0.3, 0.3, 0.35, 1), **button),
            "discard": DirectButton(text="discard", pos=(left + 0.68, 0, row2), command=self.keys.press,
                                    extraArgs=[DISCARD_KEY], frameColor=(0.3, 0.3, 0.35, 1), **button),
            "save": DirectButton(text="save", pos=(left + 0.96, 0, row2), command=self.keys.press,
                                 extraArgs=[SAVE_KEY], frameColor=(0.2, 0.35, 0.6, 1), **button),
            "exit": DirectButton(text="exit", pos=(left + 1.24, 0, row2), command=self.request_exit,
                                 frameColor=(0.55, 0.18, 0.15, 1), **button),
        }
        if self.policy is not None:   # held: the operator drives; released: the policy does
            from direct.gui.DirectGui import DGG

            take = DirectButton(text="take over", pos=(left + 1.52, 0, row2), frameColor=(0.6, 0.45, 0.05, 1),
                                **button)
            take.bind(DGG.B1PRESS, lambda _event: self.keys.hold(TAKEOVER_KEY, True))
            take.bind(DGG.B1RELEASE, lambda _event: self.keys.hold(TAKEOVER_KEY, False))
            self.buttons["take over"] = take
        self.status = DirectLabel(text="choose a task", pos=(left, 0, row3), **label)
        self._status_scale = 0.04
        # The widest row (the menus' or the buttons') sets how small the controls must be drawn to fit.
        room = aspect - EDGE_GAP - controls.get_x()
        widest = max(item.get_x() + item.get_sx() * item.getBounds()[1]
                     for item in (self.device_menu, self.operator_entry, self.skill_menu, *self.buttons.values()))
        controls.set_scale(min(1.0, room / widest))
        self._status_room = room / controls.get_sx() - left   # in the controls' units

    def _build_hud(self) -> None:
        from direct.gui.OnscreenText import OnscreenText
        from panda3d.core import TextNode

        aspect = self.size[0] / self.size[1]
        x = -aspect + 2 * aspect * PANEL_FRACTION + 0.04
        self._hud_room = aspect - EDGE_GAP - x   # from the texts' left edge to the window's right edge
        self._hud_shown: dict[int, str] = {}   # what each HUD text shows, by id
        # Light text on a dark plate: the view behind it may be anything from the black void to a lit white board,
        # and a drop shadow alone leaves light text unreadable on a light floor.
        plate = dict(bg=HUD_PLATE, shadow=(0, 0, 0, 1), mayChange=True, align=TextNode.A_left)
        self.hud_text = OnscreenText(text="", pos=(x, 0.92), scale=HUD_SCALE, fg=(0.95, 0.95, 0.6, 1), **plate)
        # The keys that work, at the foot of the view (a new user should not need the README to operate).
        self.keys_text = OnscreenText(text="", pos=(x, -1 + 2 * CONTROLS_FRACTION + 0.09), scale=KEYS_SCALE,
                                      fg=(0.85, 0.9, 1.0, 1), **plate)
        for text in (self.hud_text, self.keys_text):
            text.textNode.set_card_as_margin(*HUD_PLATE_MARGIN)

    def _show_hud_text(self, text, content: str, scale: float) -> None:
        """Show ``content`` in the HUD's ``text`` (an OnscreenText of size ``scale``), fitted to the view's width
        (measured with its plate's right margin); only when it changed (fitting measures every line)."""
        if self._hud_shown.get(id(text)) == content:
            return
        self._hud_shown[id(text)] = content
        node = text.textNode
        fitted, s = fit_text(content, lambda line: node.calc_width(line) + HUD_PLATE_MARGIN[1],
                             self._hud_room, scale, MIN_TEXT_SCALE * scale) if content else (content, scale)
        text.setScale(s)
        text.setText(fitted)

    def set_status(self, message: str) -> None:
        """Show ``message`` in the status line under the buttons, fitted to the view's width."""
        node = self.status.component("text0").textNode
        fitted, s = fit_text(message, node.calc_width, self._status_room, self._status_scale,
                             MIN_TEXT_SCALE * self._status_scale)
        self.status["text"] = fitted
        self.status.set_scale(s)

    # ------------------------------------------------------------------ task pictures and descriptions
    @staticmethod
    def _description(task: str) -> str:
        from gymnasium.envs.registration import load_env_creator

        cls = load_env_creator(gym.spec(env_id(task)).entry_point)
        return getattr(cls, "TASK", "") or (cls.__doc__ or task).strip().splitlines()[0]

    def _task_pictures(self) -> dict:
        """Each task's endoscope view after a seeded reset, drawn by this window's renderer into a texture."""
        from panda3d.core import Texture

        from surrol_data.render.env_view import EnvEndoscope
        from surrol_data.render.stage import EndoscopeStage, endoscope_lens, view_framebuffer

        pictures = {}
        for task in TASKS:
            env = gym.make(env_id(task), render_mode="rgb_array")
            env.reset(seed=self.seed)
            view = EnvEndoscope(env)
            stage = EndoscopeStage(view.client, view.scene_scale)
            tex = Texture(f"picture-{task}")
            buffer = self.base.win.make_texture_buffer(f"picture-{task}", *THUMBNAIL, tex, True,
                                                       view_framebuffer(VIEW_MULTISAMPLES))
            buffer.set_clear_color((0, 0, 0, 1))
            cam = self.base.make_camera(buffer, lens=endoscope_lens(*THUMBNAIL))
            cam.reparent_to(stage.root)
            stage.update(view.pose())
            stage.place_camera(cam)
            for _ in range(2):   # the first frame makes the light's shadow buffer
                self.base.graphicsEngine.render_frame()
            self.base.graphicsEngine.remove_window(buffer)
            stage.close()
            env.close()
            pictures[task] = tex
        return pictures

    # ------------------------------------------------------------------ actions
    def scroll_tasks(self, notches: int) -> None:
        """Scroll the task list by ``notches`` wheel notches (positive: down the list)."""
        bar = self.panel.verticalScroll
        low, high = bar["range"]
        bar.setValue(min(high, max(low, bar.getValue() + notches * _WHEEL_STEP * (high - low))))

    def choose_task(self, task: str) -> None:
        if self._session_running:
            return
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}")
        self.task = task
        for name, card in self.cards.items():
            card["frameColor"] = (0.25, 0.35, 0.5, 1) if name == task else (0.18, 0.18, 0.2, 1)
        if self._preview_env is not None:
            self._preview_env.close()
        self._preview_env = gym.make(env_id(task), render_mode="rgb_array")
        self._preview_env.reset(seed=self.seed)
        self._show_env(self._preview_env)
        act_dim = self._preview_env.action_space.shape[0]
        ecm = is_ecm_action(act_dim)   # one camera
        self.hud.task, self.hud.arms = task, 1 if ecm else act_dim // 5
        self.hud.period_s = control_period_s(self._preview_env)   # what the session paces its steps by
        self.hud.intervention = self.policy is not None
        self.set_status(f"{task}: press play")

    def set_session(self, device: str, skill: str, operator_id: str) -> None:
        """Fill the session controls (what the menus and the operator field set)."""
        if device not in DEVICES or skill not in SKILLS:
            raise ValueError(f"device must be one of {DEVICES} and skill one of {SKILLS}, got {device!r}, {skill!r}")
        self.device_menu.set(DEVICES.index(device), fCommand=False)
        self.skill_menu.set(SKILLS.index(skill), fCommand=False)
        self.operator_entry.enterText(operator_id)
        self.device, self.skill, self.operator_id = device, skill, operator_id.strip()

    def _set_device(self, name: str) -> None:
        self.device = name
        if name == "operator" and self.skill == "unknown":
            self.skill_menu.set(SKILLS.index("expert"))

    def _set_skill(self, skill: str) -> None:
        self.skill = skill

    def _set_operator(self, text: str) -> None:
        self.operator_id = text.strip()

    def _typing(self, typing: bool) -> None:
        # Keys typed into the operator field are not teleoperation or session keys.
        self.keys.enabled = not typing
        if not typing:
            self._set_operator(self.operator_entry.get())

    def play(self) -> None:
        if self.task is None:
            self.set_status("choose a task first")
            return
        if not self._session_running:
            self._play_requested = True

    def request_exit(self) -> None:
        """Exit: ends a running session (its finished episodes are saved) and closes the window."""
        self.exit_requested = True
        if self._session_running:
            self.keys.press(QUIT_KEY)

    # ------------------------------------------------------------------ drawing (the main thread)
    def _show_env(self, env) -> None:
        """Build the scene of ``env``'s PyBullet world and draw it (the session thread, if any, is waiting)."""
        from surrol_data.render.env_view import EnvEndoscope
        from surrol_data.render.stage import EndoscopeStage

        if self._stage is None or self._stage_client is not env.unwrapped.client:
            if self._stage is not None:
                self._stage.close()
            self._endoscope = EnvEndoscope(env)
            self._stage = EndoscopeStage(self._endoscope.client, self._endoscope.scene_scale)
            self._stage.root.reparent_to(self.base.render)
            self._stage_client = env.unwrapped.client
            self._redraw_view(2)
        self._sync_scene()

    def _sync_scene(self) -> None:
        """Copy the PyBullet poses into the scene: only while no session steps (or while it waits for this). Without
        PyBullet's forward-kinematics pass: a view must leave the episode it shows as it is (the one a replay of its
        actions without a window gives)."""
        if self._stage is not None:
            self._stage.update(self._endoscope.pose(), forward_kinematics=False)
            self._stage.place_camera(self._view_cam)
            self._redraw_view()

    def _draw(self) -> None:
        """One frame: the step the session thread handed over (if any) into the scene, the HUD, then Panda3D's
        frame (drawing, clicks, keys, the window's tasks); the session thread steps on after it."""
        pending = self._pending_step
        if pending is not None:
            env, step, info, flags = pending
            if self._stage_client is not env.unwrapped.client:
                self._show_env(env)
                if self._preview_env is not None:   # the session's world replaces the preview's
                    self._preview_env.close()
                    self._preview_env = None
            else:
                self._sync_scene()
            self.hud.update(step, info, flags)
        if not self._session_running:   # the menus' choices, shown before play
            self.hud.device = self.device
            self.hud.skill = "expert" if self.device == "operator" and self.skill == "unknown" else self.skill
        self._show_hud_text(self.hud_text, "\n".join(self.hud.lines()) if self.task else "", HUD_SCALE)
        self._show_hud_text(self.keys_text, "\n".join(self.hud.key_lines()) if self.task else "", KEYS_SCALE)
        drawing = self._view_frames > 0
        self._view_buffer.set_active(drawing)
        if self._stage is not None:
            self._stage.light.set_drawing(drawing)
        self.base.taskMgr.step()
        self._view_frames = max(0, self._view_frames - 1)
        self.frame_times.append(time.monotonic())
        if pending is not None:
            self.steps_drawn += 1
            self._pending_step = None
            self._step_drawn.set()

    def frame(self) -> None:
        """One frame of the window's loop: start a requested session, draw, notice a session that ended."""
        if self._play_requested:
            self._play_requested = False
            self._start_session()
        self._draw()
        if self._session_thread is not None and not self._session_thread.is_alive():
            self._session_ended()

    def run(self, screenshot: str | Path | None = None) -> None:
        """The window's loop until exit (a running session ends first, its finished episodes saved);
        ``screenshot``: write the last frame there (PNG) before closing."""
        try:
            while not self.exit_requested or self._session_thread is not None:
                start = time.monotonic()
                self.frame()
                time.sleep(max(0.0, _IDLE_FRAME_S - (time.monotonic() - start)))
            if screenshot is not None:
                self.screenshot(screenshot)
        finally:
            self.close()

    # ------------------------------------------------------------------ the session (its own thread)
    def _start_session(self) -> None:
        from surrol_data.collect.devices.keyboard import KeyTracker

        task, out = self.task, self.out / (self.task if self.policy is None else f"{self.task}_intervene")
        self.last_task = task
        skill = "expert" if self.device == "operator" and self.skill == "unknown" else self.skill
        self.hud = Hud(task=task, device=self.device, skill=skill, arms=self.hud.arms,
                       intervention=self.policy is not None, period_s=self.hud.period_s)
        self._session_running = True
        self.set_status(f"recording into {out.parent.name}/{out.name}")
        self.keys.start()
        kwargs = dict(
            device=self.device, operator_id=self.operator_id or "anonymous", skill=skill, seed=self.seed,
            keep_failures=True, append=(out / "meta" / "info.json").exists(), gui=False, progress=False,
            command=f"surrol-data gui --out {self.out}", key_tracker=KeyTracker(self.keys), on_step=self._on_step,
            env_kwargs={"render_mode": "rgb_array"}, max_attempts=SESSION_EPISODES, max_steps=self.max_steps,
            # A person watches every step: the session runs at the robot's pace for every device, the simulated
            # operator included; an attempt out of time is kept only if the operator saves it.
            realtime=True, timeout_needs_save=True, policy=self.policy, policy_info=self.policy_info)
        self._session_outcome = None
        self._session_thread = threading.Thread(target=self._session_body, args=(task, out, kwargs),
                                                name="surrol-gui-session")
        self._session_thread.start()

    def _session_body(self, task: str, out: Path, kwargs: dict) -> None:
        """The session thread: the whole haptic session, its outcome kept for the window to report."""
        from surrol_data.collect.haptic_source import collect_haptic

        try:
            self._session_outcome = collect_haptic(task, self.session_episodes, out, **kwargs)
        except BaseException as e:   # reported (or raised again) by the window's thread
            self._session_outcome = e

    def _session_ended(self) -> None:
        from surrol_data.collect.devices import DeviceError

        self._session_thread.join()
        self._session_thread = None
        self._session_running = False
        self._stage_client = None
        self.keys.stop()
        outcome, task = self._session_outcome, self.last_task
        self.exit_requested = self.exit_requested or self.exit_after_session
        if isinstance(outcome, DeviceError):
            self.last_error = f"device: {outcome}"
        elif isinstance(outcome, (ValueError, RuntimeError, FileExistsError)) and not isinstance(outcome, _WindowClosed):
            self.last_error = str(outcome)
        elif isinstance(outcome, BaseException) and not isinstance(outcome, _WindowClosed):
            raise outcome
        elif not isinstance(outcome, BaseException):
            self.last_result = outcome
        if not self.exit_requested:
            self.choose_task(task)   # the task is ready for the next play (its status line is replaced below)
        if self.last_error:
            self.set_status(self.last_error)
        elif not isinstance(outcome, BaseException):
            self.set_status(f"saved {outcome.kept} episode(s)")

    def autoplay(self, task: str, episodes: int) -> None:
        """Choose ``task``, play, and exit once ``episodes`` episodes are saved (demos, screenshots, smoke tests)."""
        self.choose_task(task)
        self.session_episodes = episodes
        self.exit_after_session = True
        self.buttons["play"].commandFunc(None)

    def _on_step(self, env, step: int, obs, info, flags) -> None:
        """The session thread, after each env step: hand the step to the window and wait until it is drawn."""
        if step == 1:
            self.hud.limit_steps = env.spec.max_episode_steps if env.spec is not None else None
        self._step_drawn.clear()
        self._pending_step = (env, step, info, flags)
        while not self._step_drawn.wait(0.05):
            if self._closing:
                raise _WindowClosed("the window closed during the session (its finished episodes are saved)")

    # ------------------------------------------------------------------ output
    def screenshot(self, path: str | Path) -> Path:
        """Write the window as it is now (PNG)."""
        from panda3d.core import Filename

        self.base.graphicsEngine.render_frame()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.base.win.get_screenshot().write(Filename.from_os_specific(str(path)))
        return path

    def close(self) -> None:
        """Close the window; a session still running ends first (its finished episodes are saved)."""
        self._closing = True
        if self._session_thread is not None:
            self.keys.press(QUIT_KEY)
            self._session_thread.join(timeout=60)
        if self._preview_env is not None:
            self._preview_env.close()
            self._preview_env = None
        self.base.destroy()

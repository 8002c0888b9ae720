"""The heads-up display of one attempt: who operates, time against the limit, success, path length, each arm's jaw
and clutch, and the keys that work (a new user should not need the README to operate)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from surrol_data.collect.devices.keyboard import DISCARD_KEY, LAYOUTS, REDO_KEY, SAVE_KEY
from surrol_data.collect.devices import SIDES
from surrol_data.envs.units import CONTROL_PERIOD_S

# How the session keys are spelled on screen.
_KEY_NAMES = {SAVE_KEY: "Enter", REDO_KEY: "r", DISCARD_KEY: "f", "esc": "Esc", " ": "space"}


def device_label(device: str, skill: str) -> str:
    """``simulated operator (expert)``: the simulated operator shows which skill it plays; a person's device its name."""
    return f"simulated operator ({skill})" if device == "operator" else device


def layout_keys(side: str) -> str:
    """One hand's keyboard keys: screen directions, roll, jaw and clutch (see :data:`LAYOUTS`)."""
    layout = LAYOUTS[side]
    by_axis = {(axis, sign): key for key, (axis, sign) in layout.motion.items()}
    roll = " ".join(sorted(layout.turn, key=lambda k: -layout.turn[k]))
    return (f"{by_axis[(1, 1.0)]} {by_axis[(0, -1.0)]} {by_axis[(1, -1.0)]} {by_axis[(0, 1.0)]} up left down right   "
            f"{by_axis[(2, 1.0)]} {by_axis[(2, -1.0)]} toward away   {roll} roll   {layout.jaw} jaw   "
            f"{layout.clutch} clutch")


@dataclass
class Hud:
    task: str = ""
    device: str = "keyboard"
    skill: str = "unknown"
    arms: int = 1
    intervention: bool = False      # an intervention session: space hands the arms to the operator
    attempt: int = 0
    steps: int = 0
    limit_steps: int | None = None  # the attempt's time limit in steps (None: not known yet)
    period_s: float = CONTROL_PERIOD_S
    success: bool = False
    path_m: float = 0.0
    jaw_closed: list[bool] = field(default_factory=lambda: [False])
    clutch: list[bool] = field(default_factory=lambda: [False])
    operator: bool | None = None    # an intervention session: the operator drives (True) or the policy (False)
    _last_tip: np.ndarray | None = field(default=None, repr=False)

    def start_attempt(self) -> None:
        self.attempt += 1
        self.steps, self.success, self.path_m = 0, False, 0.0
        self.jaw_closed, self.clutch = [False] * self.arms, [False] * self.arms
        self._last_tip = None

    def update(self, step: int, info: dict, flags: dict) -> None:
        """After env step ``step`` (1 = the first of an attempt) with the env's ``info`` and the device flags
        (``jaw_buttons`` / ``clutches``: per arm; ``jaw_button`` / ``clutch``: any arm)."""
        if step == 1:
            self.start_attempt()
        tip = np.asarray(info["tip_position"], np.float64).reshape(-1, 3)
        if self._last_tip is not None and self._last_tip.shape == tip.shape:
            self.path_m += float(np.linalg.norm(tip - self._last_tip, axis=1).sum())
        self._last_tip = tip
        self.steps = step
        self.success = self.success or bool(info["is_success"])
        self.jaw_closed = [bool(v) for v in flags.get("jaw_buttons", [flags.get("jaw_button", False)])]
        self.clutch = [bool(v) for v in flags.get("clutches", [flags.get("clutch", False)])]
        self.operator = None if "operator" not in flags else bool(flags["operator"])

    @property
    def time_s(self) -> float:
        """Simulated time of the attempt (steps × the control period)."""
        return self.steps * self.period_s

    @property
    def timed_out(self) -> bool:
        """The attempt ran to its time limit without success: it waits for the operator to save or drop it."""
        return self.limit_steps is not None and self.steps >= self.limit_steps and not self.success

    def lines(self) -> list[str]:
        if self.attempt == 0:   # before play: what the session will be
            return [f"{self.task}   {device_label(self.device, self.skill)}", "press play to start"]
        limit = "" if self.limit_steps is None else f" / {self.limit_steps * self.period_s:.3g}"
        lines = [f"{self.task}   attempt {self.attempt}   {device_label(self.device, self.skill)}",
                 f"time {self.time_s:5.1f}{limit} s   path {100 * self.path_m:5.1f} cm   "
                 f"success {'YES' if self.success else 'no'}"]
        names = ["PSM1", "PSM2"] if len(self.jaw_closed) == 2 else [""]
        lines.append("   ".join(f"{name} jaw {'closed' if jaw else 'open'}  clutch {'ON' if clutch else 'off'}".strip()
                                for name, jaw, clutch in zip(names, self.jaw_closed, self.clutch)))
        if self.operator is not None:
            lines.append("YOU DRIVE" if self.operator else "the policy acts (hold space or take over)")
        if self.timed_out:
            lines.append(f"TIME UP: {_KEY_NAMES[SAVE_KEY]} keeps this attempt, {_KEY_NAMES[DISCARD_KEY]} drops it, "
                         f"{_KEY_NAMES[REDO_KEY]} redoes it")
        return lines

    def key_lines(self) -> list[str]:
        """The keys that work now: the keyboard's per hand (keyboard device), then the session's."""
        lines = []
        if self.device == "keyboard":
            sides = SIDES[:self.arms]
            for side in sides:
                lines.append((f"{side} hand: " if len(sides) > 1 else "") + layout_keys(side))
        session = (f"{_KEY_NAMES[SAVE_KEY]} save   {_KEY_NAMES[REDO_KEY]} redo   {_KEY_NAMES[DISCARD_KEY]} discard   "
                   "Esc end the session")
        if self.intervention:
            session += "   hold space: take over"
        return [*lines, session]

"""The heads-up display's numbers for one attempt: time, success, path length so far, jaw and clutch."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from surrol_data.envs.units import CONTROL_PERIOD_S


@dataclass
class Hud:
    task: str = ""
    attempt: int = 0
    steps: int = 0
    success: bool = False
    path_m: float = 0.0
    jaw_closed: bool = False
    clutch: bool = False
    operator: bool | None = None    # an intervention session: the operator drives (True) or the policy (False)
    _last_tip: np.ndarray | None = field(default=None, repr=False)

    def start_attempt(self) -> None:
        self.attempt += 1
        self.steps, self.success, self.path_m = 0, False, 0.0
        self.jaw_closed = self.clutch = False
        self._last_tip = None

    def update(self, step: int, info: dict, flags: dict) -> None:
        """After env step ``step`` (1 = the first of an attempt) with the env's ``info`` and the device flags."""
        if step == 1:
            self.start_attempt()
        tip = np.asarray(info["tip_position"], np.float64).reshape(-1, 3)
        if self._last_tip is not None and self._last_tip.shape == tip.shape:
            self.path_m += float(np.linalg.norm(tip - self._last_tip, axis=1).sum())
        self._last_tip = tip
        self.steps = step
        self.success = self.success or bool(info["is_success"])
        self.jaw_closed = bool(flags.get("jaw_button", False))
        self.clutch = bool(flags.get("clutch", False))
        self.operator = None if "operator" not in flags else bool(flags["operator"])

    @property
    def time_s(self) -> float:
        """Simulated time of the attempt (steps × the control period)."""
        return self.steps * CONTROL_PERIOD_S

    def lines(self) -> list[str]:
        lines = [f"{self.task}   attempt {self.attempt}",
                 f"time {self.time_s:5.1f} s   path {100 * self.path_m:5.1f} cm",
                 f"success {'YES' if self.success else 'no'}",
                 f"jaw {'closed' if self.jaw_closed else 'open'}   clutch {'ON' if self.clutch else 'off'}"]
        if self.operator is not None:
            lines.append("YOU DRIVE" if self.operator else "the policy acts (hold take over)")
        return lines

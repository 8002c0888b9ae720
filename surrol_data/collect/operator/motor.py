"""A model of human motor control for a hand holding a stylus: what the hand does once the operator has
decided where to move it.

The hand pose is 4-D: stylus position (x, y, z in mm, device frame) and the one gimbal angle that drives the
tool's rotation (rad). Its trajectory is a superposition of minimum-jerk submovements (Flash & Hogan;
overlapping submovements after Flash & Henis), each planned after a reaction delay with a duration from
Fitts' law. On top of the intended path sit three involuntary components:

* signal-dependent noise (Harris & Wolpert): the endpoint of each submovement scatters in proportion to its
  amplitude, and while the hand moves a drift accumulates in proportion to its speed;
* physiological tremor: a narrow band of 8–12 Hz oscillation with a slowly beating amplitude;
* the stylus' mechanical stops: the pose never leaves the device workspace.

The hand is sampled at increasing times only (a device is read forward in time); the noise drift makes
sampling stateful.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POSE_DIM = 4   # x, y, z (mm), gimbal angle (rad)


def minimum_jerk(tau: np.ndarray | float) -> np.ndarray | float:
    """Normalised minimum-jerk position profile s(τ), τ ∈ [0, 1] → [0, 1]."""
    t = np.clip(tau, 0.0, 1.0)
    return t**3 * (10.0 - 15.0 * t + 6.0 * t**2)


MIN_JERK_PEAK_SPEED = 1.875   # peak of ds/dτ: a submovement of amplitude D over T peaks at 1.875·D/T


def fitts_duration(distance: float, width: float, intercept_s: float, slope_s_per_bit: float) -> float:
    """Movement time by Fitts' law (Shannon form): a + b·log2(D/W + 1). ``width`` is the target's tolerance."""
    if width <= 0:
        raise ValueError(f"Fitts target width must be positive, got {width}")
    return intercept_s + slope_s_per_bit * float(np.log2(max(distance, 0.0) / width + 1.0))


@dataclass
class Submovement:
    start_s: float
    duration_s: float
    displacement: np.ndarray        # (POSE_DIM,)
    cut_s: float = np.inf           # the hand stops following this submovement from here on (an abort)

    @property
    def end_s(self) -> float:
        return min(self.start_s + self.duration_s, self.cut_s)

    def offset(self, t: float) -> np.ndarray:
        tau = (min(t, self.cut_s) - self.start_s) / self.duration_s
        return self.displacement * minimum_jerk(tau)

    def speed_fraction(self, t: float) -> float:
        """|ds/dt| relative to the submovement's amplitude (1/s): 0 outside the movement."""
        if t >= self.cut_s:
            return 0.0
        tau = (t - self.start_s) / self.duration_s
        if tau <= 0.0 or tau >= 1.0:
            return 0.0
        return 30.0 * tau**2 * (1.0 - tau) ** 2 / self.duration_s


@dataclass(frozen=True)
class MotorNoise:
    """The involuntary parts of a movement, in the hand's units (mm; gimbal rad)."""
    endpoint_sd: float          # endpoint scatter per unit of submovement amplitude (signal-dependent)
    drift_sd: float             # drift accumulated per unit of distance travelled (signal-dependent)
    tremor_mm: float            # tremor amplitude at the stylus tip (mm)
    tremor_hz: float            # centre of the tremor band (8–12 Hz)
    tremor_gimbal_rad: float    # tremor of the wrist rotation


class Hand:
    """The operator's hand on the stylus for one episode.

    ``limits`` is the (POSE_DIM,) half-range of the device workspace around its centre; the pose is clamped
    there as the stylus' mechanical stops would. ``rng`` drives every random part so that an episode is
    reproducible from its seed.
    """

    def __init__(self, start: np.ndarray, limits: np.ndarray, noise: MotorNoise, rng: np.random.Generator):
        self.limits = np.asarray(limits, np.float64)
        self.noise = noise
        self.rng = rng
        self._base = np.clip(np.asarray(start, np.float64), -self.limits, self.limits)
        self._moves: list[Submovement] = []
        self._drift = np.zeros(POSE_DIM)
        self._last_t: float | None = None
        # Tremor: three components spread over the band, random phases; their beating gives the slowly
        # varying amplitude of real tremor, and sampled at the device rate they do not alias to one clean sine.
        band = np.clip(noise.tremor_hz + rng.uniform(-1.5, 1.5, size=3), 8.0, 12.0)
        self._tremor_hz = band
        self._tremor_phase = rng.uniform(0.0, 2 * np.pi, size=(3, POSE_DIM))
        self._tremor_amp = np.array([noise.tremor_mm] * 3 + [noise.tremor_gimbal_rad]) / np.sqrt(3.0)

    # ------------------------------------------------------------------ planning
    def move(self, start_s: float, displacement: np.ndarray, duration_s: float) -> Submovement:
        """Add a submovement of the intended ``displacement``; what the hand does scatters around it."""
        intended = np.asarray(displacement, np.float64)
        scatter = self.rng.normal(0.0, 1.0, POSE_DIM) * self.noise.endpoint_sd * np.abs(intended)
        # Scatter along one axis also leaks into the others (a reach is not axis-aligned motor command).
        amplitude = float(np.linalg.norm(intended[:3]))
        scatter[:3] += self.rng.normal(0.0, 0.3 * self.noise.endpoint_sd * amplitude, 3)
        sub = Submovement(start_s, max(duration_s, 0.05), intended + scatter)
        self._moves.append(sub)
        return sub

    def halt(self, at_s: float) -> None:
        """Abort every submovement at ``at_s`` (the hand freezes where it is then)."""
        for sub in self._moves:
            sub.cut_s = min(sub.cut_s, at_s)

    def busy_until(self) -> float:
        return max((m.end_s for m in self._moves), default=-np.inf)

    def remaining(self, t: float) -> np.ndarray:
        """The part of the planned motion not yet done at time ``t`` (the efference copy a person predicts with)."""
        left = np.zeros(POSE_DIM)
        for sub in self._moves:
            left += sub.offset(np.inf) - sub.offset(t)
        return left

    def planned_pose(self) -> np.ndarray:
        """Where the intended path ends once every planned submovement is done (no tremor, no drift)."""
        end = self._base.copy()
        for sub in self._moves:
            end += sub.offset(np.inf)
        return end + self._drift

    # ------------------------------------------------------------------ sampling
    def sample(self, t: float) -> np.ndarray:
        """The hand pose at time ``t`` (non-decreasing across calls)."""
        if self._last_t is not None and t < self._last_t:
            raise ValueError(f"the hand is sampled forward in time only: {t} after {self._last_t}")
        dt = 0.0 if self._last_t is None else t - self._last_t
        self._last_t = t
        speed = np.zeros(POSE_DIM)
        pose = self._base.copy()
        for sub in self._moves:
            pose += sub.offset(t)
            speed += np.abs(sub.displacement) * sub.speed_fraction(t)
        # Velocity noise: the drift random-walks with a step proportional to the distance just travelled.
        self._drift += self.rng.normal(0.0, 1.0, POSE_DIM) * self.noise.drift_sd * speed * dt
        self._retire(t)
        phase = 2 * np.pi * self._tremor_hz[:, None] * t + self._tremor_phase
        tremor = (self._tremor_amp * np.sin(phase)).sum(axis=0)
        return np.clip(pose + self._drift + tremor, -self.limits, self.limits)

    def _retire(self, t: float) -> None:
        """Fold finished submovements into the base pose so the list stays short."""
        done = [m for m in self._moves if m.end_s <= t]
        for sub in done:
            self._base += sub.offset(np.inf)
        self._moves = [m for m in self._moves if m.end_s > t]
        # Mechanical stops: a hand pushed against one stays there; the plan continues from the stop.
        self._base = np.clip(self._base, -self.limits, self.limits)

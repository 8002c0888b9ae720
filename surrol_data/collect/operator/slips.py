"""The action slips of a person at the console: what goes wrong in an act that was planned right.

Three slips, each a mechanism whose outcome the scene decides (the env's own grasp test, grip and contacts), not a
draw of the outcome:

* **closing too early**: on some grasp attempts the person is in a hurry. They accept the approach to the grasp point
  once it looks within ``early_close_slack`` × their usual accuracy, after one corrective movement at most, and press
  the jaw button while the tool is still settling. Stopped short of the wire or beside it, the blades close on
  nothing (a failed attempt the person then sees, reopens, backs off from and retries) or bite it off the grasp
  point; a tool close enough grasps as usual.
* **a descent that overshoots**: on some grasp attempts the first, ballistic movement down to the grasp point goes
  ``overshoot_mm`` (drawn around it) deeper than the person meant: the tool strikes the tray or pad beside the object
  (what the simulators score as a collision or excessive force) before the next look corrects it upwards. An
  overshoot close to the object can also push it or close on it off its grasp point.
* **a lapse of the grip**: while carrying a held object, the finger on the jaw button relaxes now and then (attention
  goes to the moving hand; a hazard of ``grip_lapse_per_s`` per second of carrying) for a moment drawn around
  ``grip_lapse_s``. A lapse shorter than the jaw's ramp (two frames) changes nothing; a longer one opens the jaw and
  the object falls where it is (a drop in transport), which the person sees and recovers from as from a failed grasp.

Every draw comes from a generator of its own (see :class:`Slips`), so a profile without slips (every rate 0) moves
exactly as before they were modelled.
"""

from __future__ import annotations

import numpy as np

# The lapse's duration: gamma-distributed (shape 4) around the person's mean: mostly a few tenths of a second.
_LAPSE_SHAPE = 4.0
# The overshoot's depth: gamma-distributed (shape 4) around the person's mean: rarely more than twice it.
_OVERSHOOT_SHAPE = 4.0


class Slips:
    """The slips of one person on one episode: ``params`` (an :class:`OperatorParams`) and ``rng`` (the episode's
    generator for slips, apart from the one the movements draw from)."""

    def __init__(self, params, rng: np.random.Generator):
        self.params = params
        self.rng = rng
        self._hurry: dict[tuple, bool] = {}
        self._overshoot: dict[tuple, float] = {}
        # A child stream: drawing overshoots leaves the hurries and lapses drawn as without them.
        self._overshoot_rng = rng.spawn(1)[0]

    def hurried(self, attempt: tuple) -> bool:
        """Whether the grasp attempt ``attempt`` (any key naming it: the plan step and the failures so far) is made
        in a hurry; drawn once per attempt."""
        if attempt not in self._hurry:
            self._hurry[attempt] = bool(self.rng.random() < self.params.early_close_probability)
        return self._hurry[attempt]

    def overshoot_mm(self, attempt: tuple) -> float:
        """How much deeper (mm) than meant the first movement down to grasp attempt ``attempt`` goes, or 0; drawn once
        per attempt, from a stream of its own."""
        if attempt not in self._overshoot:
            p = self.params
            rng = self._overshoot_rng
            overshoots = p.overshoot_probability > 0.0 and rng.random() < p.overshoot_probability
            self._overshoot[attempt] = (float(rng.gamma(_OVERSHOOT_SHAPE, p.overshoot_mm / _OVERSHOOT_SHAPE))
                                        if overshoots else 0.0)
        return self._overshoot[attempt]

    def lapse(self, period_s: float) -> float:
        """Called once a frame while carrying: the duration (s) of a lapse of the grip that starts now, or 0."""
        rate = self.params.grip_lapse_per_s
        if rate <= 0.0 or self.rng.random() >= rate * period_s:
            return 0.0
        return float(self.rng.gamma(_LAPSE_SHAPE, self.params.grip_lapse_s / _LAPSE_SHAPE))

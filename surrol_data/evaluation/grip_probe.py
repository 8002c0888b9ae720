"""The induced-failure probe: a policy's first attempt near the grasp point is made to fail, and what it does next
is watched (the paper saw human-trained policies grasp again after a failed first attempt, script-trained ones not).

:class:`InducedFailure` wraps a one-arm object task's env. Until the probe is spent, every close of the jaw (jaw
command < 0) runs with the grasp unable to form, until the jaw command opens again: the env's
``Grasp.between_blades`` answers False for this env's grasp alone (an instance attribute over the method), and the
blades pass through the object (their collisions with it are off): the jaw closes on nothing, as beside the wire.
Only the grip alone would not do: the blades' contacts squeeze the needle hard enough to lift it (measured: the
oracle lifted it to the goal with the grip off). The blades collide again once the jaw is open and clear of the
object (or at the next close). A close away from the object could not grip anyway: disabling every close before
the first attempt, rather than those that start near, catches the policies that close while still descending and
grip within that first action (the committed script policy, 6 of 10 episodes with a 1 cm arming radius).

The probe is spent on the first close near the object: the measured jaw closing, a blade within :data:`NEAR_M` of
the object — anywhere on it: trained policies grip the needle 6–26 mm from the mid-arc point the attempt measure's
grasp point is — at its start or after its first action. Unlike the attempt measure's rule it takes one-step
closes: the committed script policy grasps by closing for one step and reopening unless it gripped, so under a
two-step rule it never spent the probe and every grasp it tried was disabled. Every later close grips as usual, so
exactly one close near the object is disabled; the later closes near it, or that hold it, are its retries
(:attr:`ProbeRecord.retries`).

Each step's info says whether the grip was disabled (``grip_disabled``); after the episode
:attr:`InducedFailure.record` gives the step the disabled attempt began and whether a grip was prevented.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from surrol_data.datasets.attempts import JAW_CLOSING_RAD, NEAR_M, ONE_ARM_OBJECT_OBS_DIM
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import JAW_JOINTS
from surrol_data.envs.units import SCALING



@dataclass
class ProbeRecord:
    disabled_from: int = -1       # the action index where the disabled attempt began (-1: the probe never fired)
    disabled_steps: int = 0       # actions with the grip disabled, over all closes it covered
    prevented_grip: bool = False  # the blades met the object between them during the disabled attempt (it would
    #                               have gripped; False: it closed beside the object anyway)
    spent: bool = False           # one attempt was disabled; the grip is as usual from then on
    retries: int = 0              # closes near the object after the disabled one (or that held it)


class InducedFailure(gym.Wrapper):
    """Disable the grip for the first attempt near the grasp point (see the module docstring)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        base = env.unwrapped
        grasp = getattr(base, "grasp", None)
        if grasp is None or not callable(getattr(type(grasp), "between_blades", None)):
            raise ValueError(f"{type(base).__name__} has no single grasp to disable; the induced-failure probe is for "
                             "one-arm tasks that grasp an object (e.g. NeedlePick)")
        if env.observation_space["observation"].shape[0] != ONE_ARM_OBJECT_OBS_DIM:
            raise ValueError(f"{type(base).__name__}'s observation has no grasp point: the induced-failure probe is "
                             "for one-arm tasks that grasp an object (e.g. NeedlePick)")
        self._grasp = grasp
        self._passing = False             # the blades' collisions with the object are off
        self.record = ProbeRecord()
        self._close: dict | None = None   # the jaw close under way
        self._t = 0

    def reset(self, **kwargs):
        self._enable()
        self._passing = False   # (the env's reset respawns the object: its collisions are as built)
        self.record = ProbeRecord()
        self._close, self._t = None, 0
        obs, info = self.env.reset(**kwargs)
        return obs, {**info, "grip_disabled": False}

    def step(self, action):
        closing = float(np.asarray(action).reshape(-1)[4]) < 0
        if self._passing and (self._close is None or not self._close["disabled"]) \
                and (closing or self._blades_clear()):
            self._collide(True)
        if self._close is not None and not closing:
            self._close_ends()
        if self._close is None and closing:
            distance = self._blade_distance()
            disabled = not self.record.spent and not self._grasp.attached
            self._close = {"start": self._t, "jaw": self._grasp.psm.jaw_angle(), "min_jaw": np.inf, "steps": 0,
                           "near": distance <= NEAR_M, "held": False, "disabled": disabled, "prevented": False}
            if disabled:
                self._disable()
        disabled = self._close is not None and self._close["disabled"]
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._close is not None:
            c = self._close
            c["steps"] += 1
            c["min_jaw"] = min(c["min_jaw"], self._grasp.psm.jaw_angle())
            c["held"] = c["held"] or self._grasp.attached
            if c["steps"] == 1:
                c["near"] = c["near"] or self._blade_distance() <= NEAR_M
            self.record.disabled_steps += int(c["disabled"])
            if terminated or truncated:
                self._close_ends()
        self._t += 1
        return obs, reward, terminated, truncated, {**info, "grip_disabled": disabled}

    def close(self):
        self._enable()
        if self._passing and getattr(self._grasp.client, "_client", -1) >= 0:
            self._collide(True)
        return super().close()

    # ------------------------------------------------------------------ internals
    def _close_ends(self) -> None:
        """A close ended (the jaw command opened, or the episode ended). The disabled one spends the probe if it was
        an attempt; a later one that held, or was an attempt, is a retry."""
        c, self._close = self._close, None
        # (no least length: a trained policy's grasp may be a one-step close that it holds only if it gripped)
        attempt = c["jaw"] - c["min_jaw"] >= JAW_CLOSING_RAD and c["near"]
        if c["disabled"]:
            self._enable()
            if attempt:
                self.record.spent = True
                self.record.disabled_from = c["start"]
                self.record.prevented_grip = c["prevented"]
        elif self.record.spent and (attempt or c["held"]):
            self.record.retries += 1

    def _blade_distance(self) -> float:
        """How far (real metres) the nearer blade is from the object, up to NEAR_M (inf beyond)."""
        g = self._grasp
        reach = NEAR_M * SCALING
        with self._colliding():
            found = [p[8] for link in JAW_JOINTS
                     for p in pb.getClosestPoints(g.psm.body, g.object_id, reach, link, g.object_link,
                                                  physicsClientId=g.client._client)]
        return max(min(found), 0.0) / SCALING if found else float("inf")

    @contextmanager
    def _colliding(self):
        """The blades' collision filter as built while PyBullet is asked about them: its closest-point queries
        honour the filter, so blades passing through the object would read as far from it."""
        passing = self._passing
        if passing:
            self._collide(True)
        try:
            yield
        finally:
            if passing:
                self._collide(False)

    def _blocked(self) -> bool:
        with self._colliding():
            between = type(self._grasp).between_blades(self._grasp)
        if between and self._close is not None:
            self._close["prevented"] = True
        return False

    def _disable(self) -> None:
        self._grasp.between_blades = self._blocked   # shadows the method on this env's grasp only
        self._collide(False)

    def _enable(self) -> None:
        """The grip back (the blades' collisions come back once they are clear of the object: see ``step``)."""
        self._grasp.__dict__.pop("between_blades", None)

    def _collide(self, enabled: bool) -> None:
        g = self._grasp
        for link in JAW_JOINTS:
            pb.setCollisionFilterPair(g.psm.body, g.object_id, link, g.object_link, int(enabled),
                                      physicsClientId=g.client._client)
        self._passing = not enabled

    def _blades_clear(self) -> bool:
        g = self._grasp
        return not any(pb.getClosestPoints(g.psm.body, g.object_id, 0.0, link, g.object_link,
                                           physicsClientId=g.client._client) for link in JAW_JOINTS)

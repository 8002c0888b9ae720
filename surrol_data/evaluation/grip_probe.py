"""The induced-failure probe: a policy's first attempt near the grasp point is made to fail, and what it does next
is watched (the paper saw human-trained policies grasp again after a failed first attempt, script-trained ones not).

:class:`InducedFailure` wraps a one-arm object task's env. From the first close of the jaw (jaw command < 0) that
starts with the tool tip within :data:`ARM_RADIUS_M` of the object's grasp point, until the jaw command opens
again, the grasp cannot form: the env's ``Grasp.between_blades`` answers False for this env's grasp alone (an
instance attribute over the method), and the blades pass through the object (their collisions with it are off):
the jaw closes on nothing, as beside the wire. Only the grip alone would not do: the blades' contacts squeeze the
needle hard enough to lift it (measured: the oracle lifted it to the goal with the grip off). The blades collide
again once the jaw is open and clear of the object (or at the next close).
The probe is spent on the first such close that is an attempt by :mod:`surrol_data.datasets.attempts`' rules
(long enough, the jaw closing, near the grasp point); a shorter or farther close re-arms it (it grips nothing
meanwhile: a one-step close at the needle would have gripped, and the probed episode differs there). Every later
close grips as usual, so exactly one attempt — the first the measure sees — is disabled.

Each step's info says whether the grip was disabled (``grip_disabled``); after the episode
:attr:`InducedFailure.record` gives the step the disabled attempt began and whether a grip was prevented.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from surrol_data.datasets.attempts import (ATTEMPT_MIN_STEPS, JAW_CLOSING_RAD, NEAR_M, ONE_ARM_OBJECT_OBS_DIM,
                                           WAYPOINT_DIMS)
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import JAW_JOINTS

# The grip is disabled from any close that starts this near the grasp point: wider than the attempt rule's NEAR_M,
# so that a close the measure counts from its second state (the tip moved in during the first action) is covered.
ARM_RADIUS_M = 2 * NEAR_M


@dataclass
class ProbeRecord:
    disabled_from: int = -1       # the action index where the disabled attempt began (-1: the probe never fired)
    disabled_steps: int = 0       # actions with the grip disabled, over all closes it covered
    prevented_grip: bool = False  # the blades met the object between them during the disabled attempt (it would
    #                               have gripped; False: it closed beside the object anyway)
    spent: bool = False           # one attempt was disabled; the grip is as usual from then on


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
            raise ValueError(f"{type(base).__name__}'s observation has no grasp point: the induced-failure probe is for "
                             "one-arm tasks that grasp an object (e.g. NeedlePick)")
        self._grasp = grasp
        self._passing = False             # the blades' collisions with the object are off
        self.record = ProbeRecord()
        self._obs = None
        self._on = False
        self._run: list[np.ndarray] = []   # the observations of the current disabled close (its states)
        self._t = 0

    def reset(self, **kwargs):
        self._enable()
        self._passing = False   # (the env's reset respawns the object: its collisions are as built)
        self.record = ProbeRecord()
        self._on, self._run, self._t = False, [], 0
        self._obs, info = self.env.reset(**kwargs)
        return self._obs, {**info, "grip_disabled": False}

    def step(self, action):
        closing = float(np.asarray(action).reshape(-1)[4]) < 0
        if self._passing and not self._on and (closing or self._blades_clear()):
            self._collide(True)
        if self._on and not closing:
            self._close_ends()
        elif not self._on and closing and not self.record.spent and not self._grasp.attached \
                and self._distance(self._obs) <= ARM_RADIUS_M:
            self._on, self._run, self._prevented = True, [self._obs["observation"]], False
            self._started = self._t
            self._disable()
        disabled = self._on
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._on:
            self.record.disabled_steps += 1
            self._run.append(obs["observation"])
        self._obs, self._t = obs, self._t + 1
        if self._on and (terminated or truncated):
            self._close_ends()
        return obs, reward, terminated, truncated, {**info, "grip_disabled": disabled}

    def close(self):
        self._enable()
        if self._passing and getattr(self._grasp.client, "_client", -1) >= 0:
            self._collide(True)
        return super().close()

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _distance(obs) -> float:
        o = np.asarray(obs["observation"], np.float64)
        return float(np.linalg.norm(o[:3] - o[WAYPOINT_DIMS]))

    def _close_ends(self) -> None:
        """The disabled close ended (the jaw command opened, or the episode ended): spent if it was an attempt."""
        self._on = False
        self._enable()
        states = np.asarray(self._run, np.float64)
        steps = len(states) - 1
        closing = steps >= 1 and states[0, 6] - states[1:, 6].min() >= JAW_CLOSING_RAD
        near = min(float(np.linalg.norm(s[:3] - s[WAYPOINT_DIMS])) for s in states[:2]) <= NEAR_M
        if steps >= ATTEMPT_MIN_STEPS and closing and near:
            self.record.spent = True
            self.record.disabled_from = self._started
            self.record.prevented_grip = self._prevented

    def _blocked(self) -> bool:
        if type(self._grasp).between_blades(self._grasp):
            self._prevented = True
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

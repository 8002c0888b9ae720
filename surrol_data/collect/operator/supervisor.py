"""The simulated operator as a supervisor: it watches a policy's rollout and takes the stylus over when a person would.

A person supervising a policy (``surrol-data collect --source intervene --device operator``) rests a hand on the
stylus and watches. They take over — hold the takeover control and drive — when they see trouble:

* **no progress**: for :data:`PATIENCE_S` the task has come no closer (the tool to the object it should grasp, the
  object to its goal) by :data:`PROGRESS_M`;
* **a failed grasp**: the jaw closed, the tool moved on, and the object did not come along;
* **a drop**: the object the tool held is no longer held (it slipped out of the closed jaw, or the jaw let it go);
* **the tool leaving the workspace**: the tip is more than :data:`WORKSPACE_SLACK_M` outside the task's workspace.

The takeover starts one reaction time (the skill profile's, with its jitter) after the trouble shows, and the
operator model then drives from the scene as it is (:meth:`SimulatedOperator.take_over`). It hands back — releases
the control — once recovered: the object held for :data:`HOLD_TO_HAND_BACK_S` after a grasp problem, or the task
:data:`RECOVERED_FRACTION` closer than when it took over (the tool back on course). After :data:`MAX_HAND_BACKS`
hand-backs in one episode the person stops trusting the policy and finishes the episode.

Every draw comes from generators seeded by (seed, operator identity, the episode's key): the same person on the same
episode supervises the same way.
"""

from __future__ import annotations

import numpy as np

from surrol_data.collect.devices.base import BUTTON_TAKEOVER, Device, DeviceFrame
from surrol_data.collect.operator.motor import POSE_DIM
from surrol_data.collect.operator.operator import SimulatedOperator, episode_key
from surrol_data.envs.physics import JAW_OPEN_RAD

PATIENCE_S = 1.5             # no progress for this long and a person intervenes
PROGRESS_M = 0.001           # what counts as progress: the task 1 mm closer than its best so far
WORKSPACE_SLACK_M = 0.003    # the tip this far outside the task's workspace is leaving it
HOLD_TO_HAND_BACK_S = 1.0    # after a grasp problem: the object held this long is a recovery
RECOVERED_FRACTION = 0.5     # otherwise: the task this much closer than at the takeover
MAX_HAND_BACKS = 1           # hand-backs in one episode before the person keeps control (trust, once lost, is lost)
_LIFT_TO_NOTICE_M = 0.002    # a closed jaw that moved this far without the object: a failed grasp


class Supervisor(Device):
    """Wraps a :class:`SimulatedOperator` (one arm) into a supervisor of a policy (see the module docstring).

    While the policy acts, :meth:`read` returns the hand resting where it is, no button held; while the person drives,
    the operator's frames with :data:`BUTTON_TAKEOVER` held. :attr:`events` lists (seconds into the episode, event):
    ``takeover:<reason>`` and ``hand-back``.
    """

    name = "simulated-operator"

    def __init__(self, operator: SimulatedOperator, patience_s: float = PATIENCE_S,
                 max_hand_backs: int = MAX_HAND_BACKS):
        if not isinstance(operator, SimulatedOperator):
            raise TypeError(f"Supervisor wraps a SimulatedOperator, got {type(operator).__name__}")
        self.operator = operator
        self.view = operator.view
        self.patience_s, self.max_hand_backs = float(patience_s), int(max_hand_backs)
        self._marker = None
        self._obs: dict | None = None
        self._info: dict = {}

    # ------------------------------------------------------------------ Device API
    def connect(self) -> None:
        self.operator.connect()

    def disconnect(self) -> None:
        self.operator.disconnect()

    def settings(self) -> dict:
        return {**self.operator.settings(), "supervisor": {
            "patience_s": self.patience_s, "progress_m": PROGRESS_M, "workspace_slack_m": WORKSPACE_SLACK_M,
            "hold_to_hand_back_s": HOLD_TO_HAND_BACK_S, "recovered_fraction": RECOVERED_FRACTION,
            "max_hand_backs": self.max_hand_backs}}

    @property
    def events(self) -> tuple[tuple[float, str], ...]:
        return tuple(self._events)

    @property
    def in_control(self) -> bool:
        return self._driving

    def observe(self, obs: dict, info: dict) -> None:
        self.operator.observe(obs, info)     # the person watches every frame, driving or not
        self._obs, self._info = obs, info
        marker = self.view.episode_marker()
        if marker is not self._marker:
            self._marker = marker
            self._begin_episode()

    def read(self) -> DeviceFrame:
        if self._obs is None:
            return self.operator.read()      # raises the operator's clear error
        t = self._step * self.operator._period
        self._step += 1
        if self._driving:
            if self._recovered(t):
                self._driving = False
                self._hand_backs += 1
                self._events.append((t, "hand-back"))
                self._watch_from(t)
                return self._resting(t)
            return self._driven(t)
        reason = self._trouble(t)
        if reason is not None and self._noticed is None:
            self._noticed = (t + self._reaction(), reason)
        if self._noticed is not None and t >= self._noticed[0]:
            self._take_over(t, self._noticed[1])
            return self._driven(t)
        return self._resting(t)

    def _driven(self, t: float) -> DeviceFrame:
        """The operator's frame with the takeover control held; the hand rests where it leaves off."""
        frame = self.operator.read()
        self._pose = np.array([*frame.position_mm, frame.gimbal_rad[self.operator.mapping.rotation_axis]])
        return DeviceFrame(frame.position_mm, frame.gimbal_rad, frame.buttons | BUTTON_TAKEOVER, self._t0 + t)

    # ------------------------------------------------------------------ watching
    def _begin_episode(self) -> None:
        op = self.operator
        self._rng = np.random.default_rng(np.random.SeedSequence([op.seed, op._identity, op.arm, 7,
                                                                  *episode_key(op.env)]))
        self._t0 = getattr(self, "_t0", 0.0) + getattr(self, "_step", 0) * op._period
        self._step = 0
        self._pose = np.zeros(POSE_DIM)
        self._driving = False
        self._hand_backs = 0
        self._reason = ""
        self._events: list[tuple[float, str]] = []
        self._watch_from(0.0)

    def _watch_from(self, t: float) -> None:
        self._best = self._distance()
        self._best_t = t
        self._noticed: tuple[float, str] | None = None
        self._closed_at = None
        self._drops = self._drop_count()
        self._held = bool(self._state()[1].get("grasped", False))

    def _reaction(self) -> float:
        p = self.operator.params
        return p.reaction_time_s * max(0.4, 1.0 + p.reaction_jitter * self._rng.normal())

    def _state(self) -> tuple[np.ndarray, dict]:
        view = self.view
        return np.asarray(view.observation(self._obs)["observation"], np.float64), view.info(self._info)

    def _distance(self) -> float:
        """How far the task still is, as a person sees it (m): the tool to the object it has yet to grasp, plus the
        object (or the tool) to the goal; for the camera, the view's remaining error."""
        state, info = self._state()
        view = self.view
        if view.kind == "camera":
            return float(np.linalg.norm(state[:3]))
        o = view.observation(self._obs)
        gap = float(np.linalg.norm(np.asarray(o["achieved_goal"], np.float64)
                                   - np.asarray(o["desired_goal"], np.float64)))
        if view.has_object and view.uses_jaw and not info.get("grasped", False):
            gap += float(np.linalg.norm(state[13:16] - state[0:3]))
        return gap

    def _drop_count(self) -> int:
        return int(np.sum(self._info.get("drops", 0))) if self._info else 0

    def _trouble(self, t: float) -> str | None:
        """What a person would step in for now, or None."""
        state, info = self._state()
        d = self._distance()
        if d < self._best - PROGRESS_M:
            self._best, self._best_t = d, t
        held = bool(info.get("grasped", False))
        lost, self._held = self._held and not held, held
        if lost or self._drop_count() > self._drops:
            return "drop"
        if self.view.has_object and self.view.uses_jaw and self._grasp_failed(state, held):
            return "failed-grasp"
        if self.view.kind != "camera" and self._outside_workspace(state[0:3]):
            return "workspace"
        if t - self._best_t >= self.patience_s:
            return "no-progress"
        return None

    def _grasp_failed(self, state: np.ndarray, held: bool) -> bool:
        """The jaw closed without the object, and the tool has moved on since (call every frame it may fail)."""
        closed = state[6] < 0.1 * JAW_OPEN_RAD and not held
        if closed and self._closed_at is None:
            self._closed_at = state[0:3].copy()
        elif not closed:
            self._closed_at = None
        return self._closed_at is not None and np.linalg.norm(state[0:3] - self._closed_at) > _LIFT_TO_NOTICE_M

    def _outside_workspace(self, tip: np.ndarray) -> bool:
        from surrol_data.envs.psm_env import WORKSPACE

        box = np.asarray(getattr(self.operator.env, "WORKSPACE", WORKSPACE), np.float64)
        return bool(np.any(tip < box[:, 0] - WORKSPACE_SLACK_M) or np.any(tip > box[:, 1] + WORKSPACE_SLACK_M))

    # ------------------------------------------------------------------ driving
    def _take_over(self, t: float, reason: str) -> None:
        self._driving = True
        self._reason = reason
        self._events.append((t, f"takeover:{reason}"))
        self._taken_distance = self._distance()
        self._held_since: float | None = None
        self._grasp_problem = reason in ("failed-grasp", "drop") or self._grasp_is_due()
        self._start_driving(reason)

    def _grasp_is_due(self) -> bool:
        """The takeover is about a grasp still to make (the hand-back waits for the object held)."""
        _, info = self._state()
        return self.view.has_object and self.view.uses_jaw and not info.get("grasped", False)

    def _start_driving(self, reason: str) -> None:
        self.operator.take_over(self._obs, self._info, self._pose)

    def _back_on_course(self) -> bool:
        """Recovered from a takeover that was not about a grasp."""
        return self._distance() <= RECOVERED_FRACTION * self._taken_distance

    def _recovered(self, t: float) -> bool:
        """Back on course: hand the policy the control again (unless trust is gone, or the task is done)."""
        if self._hand_backs >= self.max_hand_backs or self._info.get("is_success", 0.0):
            return False
        state, info = self._state()
        if self.view.kind != "camera" and self._outside_workspace(state[0:3]):
            return False
        if self._grasp_problem:
            if not info.get("grasped", False):
                self._held_since = None
                return False
            if self._held_since is None:
                self._held_since = t
            return t - self._held_since >= HOLD_TO_HAND_BACK_S
        return self._back_on_course()

    def _resting(self, t: float) -> DeviceFrame:
        gimbal = np.zeros(3)
        gimbal[self.operator.mapping.rotation_axis] = self._pose[3]
        return DeviceFrame(self._pose[:3].copy(), gimbal, 0, self._t0 + t)

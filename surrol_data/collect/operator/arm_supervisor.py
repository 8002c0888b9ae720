"""The simulated supervisor on a two-arm task: one watch per arm, takeover per arm.

A person supervising a policy on NeedleRegrasp or BiPegTransfer watches both tools and takes over the one that goes
wrong, with that hand, while the policy keeps the other (``collect --source intervene --device operator`` on a
two-arm task makes one :class:`ArmSupervisor` per arm). What each arm should be doing comes from the phase of the
plan the scene is in (:class:`~surrol_data.collect.operator.plan_phases.PlanPhases`: who holds the object, and
each arm's part until the next grasp or release). An arm is taken over, one reaction time after the trouble shows
(the skill profile's reaction time and jitter, drawn for that hand), for:

* **no progress**: for :data:`~surrol_data.collect.operator.supervisor.PATIENCE_S` its part has come no closer
  by :data:`~surrol_data.collect.operator.supervisor.PROGRESS_M` (and the phase has not moved on), while there is
  some left (it is not just waiting for the other arm);
* **a drop**: it let go of the object where the plan does not (no other arm holds it, and it was more than
  :data:`RELEASE_SLACK_M` from where the plan lets go);
* **a failed grasp**: its part is a grasp, the jaw closed without the object, and the tool moved on 2 mm;
* **leaving the workspace**: its tip more than
  :data:`~surrol_data.collect.operator.supervisor.WORKSPACE_SLACK_M` outside its own workspace;
* **a collision coming**: the two tips closer than :data:`COLLISION_M` and closing by :data:`CLOSING_M` a frame;
  the arm that moved more towards the other is taken.

The operator model then drives that arm from the phase's first step (after a drop, from the phase where it
grasps), through :meth:`SimulatedOperator.take_over` with ``start`` and the phases as its gate: a hand-over step
waits until the policy's arm has done its part. The arm is
handed back once recovered: after a grasp problem (or a takeover whose part was a grasp) when it has held the object
for :data:`~surrol_data.collect.operator.supervisor.HOLD_TO_HAND_BACK_S`; otherwise when its part of the phase is
done or the phase has moved on. After one hand-back of an arm, that arm's next takeover lasts to the end of the
episode. Every draw comes from (seed, operator identity, arm, the episode): the same person on the same episode
supervises the same way.
"""

from __future__ import annotations

import numpy as np

from surrol_data.collect.operator.operator import SimulatedOperator
from surrol_data.collect.operator.plan_phases import EVENT_M, PlanPhases
from surrol_data.collect.operator.supervisor import PROGRESS_M, WORKSPACE_SLACK_M, Supervisor

COLLISION_M = 0.006       # the two tips this close ...
CLOSING_M = 0.0005        # ... and this much closer than a frame before: a collision is coming
RELEASE_SLACK_M = 0.005   # letting go this near the plan's release point is a release, not a drop


class _Watch:
    """What both hands' supervisors see of the scene: the phase of the plan, updated once a frame."""

    def __init__(self):
        self.marker = None
        self.obs = None
        self.phases: PlanPhases | None = None
        self.tips = None          # (2, 3) this frame's tips and the frame before's
        self.tips_before = None

    def see(self, env, marker, obs: dict, info: dict) -> None:
        if marker is not self.marker:
            self.marker, self.phases, self.tips = marker, PlanPhases(env), None
        if obs is self.obs:
            return
        self.obs = obs
        self.phases.update(np.asarray(info.get("grasped", (False, False))))
        state = np.asarray(obs["observation"], np.float64)
        self.tips_before, self.tips = self.tips, np.stack([state[0:3], state[7:10]])


class ArmSupervisor(Supervisor):
    """Supervises arm ``operator.arm`` of a two-arm task (see the module docstring); make them with
    :func:`arm_supervisors`."""

    def __init__(self, operator: SimulatedOperator, watch: _Watch, **kwargs):
        super().__init__(operator, **kwargs)
        if self.view.kind != "bimanual-arm":
            raise ValueError(f"ArmSupervisor watches one arm of a two-arm task, not a {self.view.kind} task")
        self.arm = operator.arm
        self.watch = watch

    def settings(self) -> dict:
        base = super().settings()
        base["supervisor"].update(per_arm=True, collision_m=COLLISION_M, closing_m=CLOSING_M,
                                  release_slack_m=RELEASE_SLACK_M, event_m=EVENT_M)
        return base

    def observe(self, obs: dict, info: dict) -> None:
        self.watch.see(self.operator.env, self.view.episode_marker(), obs, info)
        super().observe(obs, info)

    # ------------------------------------------------------------------ watching
    @property
    def phases(self) -> PlanPhases:
        return self.watch.phases

    def _watch_from(self, t: float) -> None:
        super()._watch_from(t)
        self._moves = self.phases.moved
        self._before = (self._distance(), self.phases.lets_go_here(self.arm))

    def _distance(self) -> float:
        return self.phases.remaining(self.arm, self._obs)

    def _others_hold(self) -> bool:
        return bool(np.asarray(self._info.get("grasped", (False, False))).reshape(-1)[1 - self.arm])

    def _trouble(self, t: float) -> str | None:
        state, info = self._state()
        phases = self.phases
        d = self._distance()
        if phases.moved != self._moves:            # the phase moved on: that is progress, for both hands
            self._moves, self._best, self._best_t = phases.moved, d, t
        elif d < self._best - PROGRESS_M:
            self._best, self._best_t = d, t
        (d_before, let_go_here), self._before = self._before, (d, phases.lets_go_here(self.arm))
        held = bool(info.get("grasped", False))
        lost, self._held = self._held and not held, held
        if lost and not self._others_hold() and not (let_go_here and d_before - EVENT_M <= RELEASE_SLACK_M):
            return "drop"
        if self._grasp_is_due() and self._grasp_failed(state, held):      # its part is a grasp: watch the jaw
            return "failed-grasp"
        if self._outside_workspace(state[0:3]):
            return "workspace"
        if self._collision_coming():
            return "collision"
        if d > PROGRESS_M and t - self._best_t >= self.patience_s:
            return "no-progress"
        return None

    def _outside_workspace(self, tip: np.ndarray) -> bool:
        box = np.asarray(self.operator.env.WORKSPACES[self.arm], np.float64)
        return bool(np.any(tip < box[:, 0] - WORKSPACE_SLACK_M) or np.any(tip > box[:, 1] + WORKSPACE_SLACK_M))

    def _collision_coming(self) -> bool:
        now, before = self.watch.tips, self.watch.tips_before
        if before is None:
            return False
        gap_now, gap_before = np.linalg.norm(now[0] - now[1]), np.linalg.norm(before[0] - before[1])
        if gap_now >= COLLISION_M or gap_before - gap_now < CLOSING_M:
            return False
        # Who closed the gap: each tip's motion along the line towards the other.
        towards = [float(np.dot(now[a] - before[a], before[1 - a] - before[a]) / max(gap_before, 1e-9))
                   for a in (0, 1)]
        return towards[self.arm] >= towards[1 - self.arm]

    # ------------------------------------------------------------------ driving
    def _grasp_is_due(self) -> bool:
        p = self.phases.phase
        return not p.holds[self.arm] and p.then[self.arm]

    def _start_driving(self, reason: str) -> None:
        # After a drop the arm grasps again: from the phase in which it grasps (the scene's phase may be past it).
        p = self.phases.grasp_phase(self.arm) if reason == "drop" else self.phases.phase
        self._taken_moves = self.phases.moved
        self.operator.take_over(self._obs, self._info, self._pose, start=p.first, gate=self.phases)

    def _back_on_course(self) -> bool:
        return self.phases.moved != self._taken_moves or self._distance() <= PROGRESS_M


def arm_supervisors(operators: list[SimulatedOperator], **kwargs) -> list[ArmSupervisor]:
    """One supervisor per arm of a two-arm task (``operators``: one per arm, not made to work together),
    sharing one watch of the scene."""
    arms = sorted(op.arm for op in operators)
    if arms != [0, 1] or len({id(op.env) for op in operators}) != 1:
        raise ValueError(f"arm_supervisors takes one operator per arm of one two-arm env, got arms {arms}")
    watch = _Watch()
    return [ArmSupervisor(op, watch, **kwargs) for op in operators]

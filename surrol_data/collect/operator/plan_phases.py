"""Where a two-arm task stands, as a person watching it sees it: the phase of the plan, and each arm's part in it.

A person supervising a policy on a two-arm task (NeedleRegrasp, BiPegTransfer) does not follow the policy's steps;
they see who holds the object. The task's plan (``BimanualEnv.oracle_waypoints``) splits by that into **phases**:
runs of steps that begin with the same arms holding (an arm holds during a step when its jaw closed in the step
before; at the first step, ``HELD_AT_START``). A phase ends with an **event**: an arm grasps the object or lets go.
NeedleRegrasp: PSM1 holds → both hold (PSM2 grasped) → PSM2 holds (PSM1 let go). BiPegTransfer: nobody → PSM2 →
both → PSM1 → nobody (on the goal peg).

Each arm's **part** in a phase is where it has to be (its target at the phase's last step that is not a loose "stay
about here": ``tol`` under :data:`~surrol_data.collect.operator.views.LOOSE_TOL_M`) and whether the phase's event is
its (grasp or let go). :meth:`PlanPhases.remaining` is how much of its part an arm still has to do, in metres; the
supervisor watches that for progress and hands back when it is done. In the last phase only an arm that holds the
object has a part: bringing it to the goal (the others only stay out of the way).

The phase follows the scene: grasps that match the next phase move to it (or the one after: a hand-over that was
quick may skip the phase in which both hold); a grasp state that matches neither (the object dropped) goes back to
the latest earlier phase that matches it, where the grasp is made again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from surrol_data.collect.operator.views import LOOSE_TOL_M

EVENT_M = 0.005     # an arm's grasp or release still to make counts as this much of its part left to do (m)


@dataclass(frozen=True)
class Phase:
    first: int                     # the plan's step indices [first, last]
    last: int
    holds: tuple[bool, bool]       # which arms hold the object while it lasts
    then: tuple[bool, bool]        # ... and after its event (the next phase's holds; the last phase: its own)


def phases_of(plan: list[dict], held_at_start: int | None) -> list[Phase]:
    """The phases of a two-arm plan (``oracle_waypoints``), in order."""
    if not plan:
        raise ValueError("a two-arm task without a plan (oracle_waypoints is empty): the supervisor cannot tell "
                         "what each arm should do")
    closed = [tuple(float(wp["arms"][a]["jaw"]) < 0 for a in (0, 1)) for wp in plan]
    start = tuple(held_at_start == a for a in (0, 1))
    holds = [start] + closed[:-1]
    runs: list[list[int]] = []
    for i, h in enumerate(holds):
        if runs and holds[runs[-1][0]] == h:
            runs[-1].append(i)
        else:
            runs.append([i])
    return [Phase(r[0], r[-1], holds[r[0]], holds[runs[k + 1][0]] if k + 1 < len(runs) else holds[r[0]])
            for k, r in enumerate(runs)]


class PlanPhases:
    """The phase of ``env``'s plan that the scene is in (see the module docstring); :meth:`update` every frame."""

    def __init__(self, env):
        self.env = env
        self.plan = env.oracle_waypoints
        self.phases = phases_of(self.plan, env.HELD_AT_START)
        self.index = 0
        self.moved = 0         # phase changes so far (a supervisor counts a change as progress)

    @property
    def phase(self) -> Phase:
        return self.phases[self.index]

    @property
    def last(self) -> bool:
        return self.index == len(self.phases) - 1

    def update(self, grasped) -> bool:
        """Follow the scene's grasps ((2,) bool); True when the phase changed."""
        holds = tuple(bool(g) for g in np.asarray(grasped).reshape(-1)[:2])
        if holds == self.phase.holds:
            return False
        # Forward only by the next event, or the next two at once (a quick hand-over: one grasps as the other lets
        # go); nobody holding after PSM2 lifted a block is a drop, not the last phase.
        later = [k for k in range(self.index + 1, min(self.index + 3, len(self.phases)))
                 if self.phases[k].holds == holds]
        earlier = [k for k in range(self.index) if self.phases[k].holds == holds]
        if later:
            self.index = later[0]
        elif earlier:
            self.index = earlier[-1]
        else:
            return False           # no phase of the plan looks like this (the object fell where no arm can get it)
        self.moved += 1
        return True

    def grasp_phase(self, arm: int) -> Phase:
        """The latest phase up to this one whose event is ``arm``'s grasp (where it grasps again after a drop);
        this phase when there is none."""
        grasps = [p for p in self.phases[:self.index + 1] if not p.holds[arm] and p.then[arm]]
        return grasps[-1] if grasps else self.phase

    def lets_go_here(self, arm: int) -> bool:
        """The plan has ``arm`` let go of the object at the end of this phase."""
        p = self.phase
        return p.holds[arm] and not p.then[arm] and not self.last

    def target(self, arm: int, raw_obs: dict) -> tuple[np.ndarray, float] | None:
        """(tip target (m), tolerance (m)) of ``arm``'s part in this phase; None when it has no place to be."""
        p = self.phase
        if self.last and not p.holds[arm]:
            return None
        for i in range(p.last, p.first - 1, -1):
            step = self.plan[i]["arms"][arm]
            tol = float(step.get("tol", 1e-3))
            if tol < LOOSE_TOL_M:
                target = step["target"](raw_obs) if callable(step["target"]) else step["target"]
                return np.asarray(target, np.float64), tol
        return None

    def remaining(self, arm: int, raw_obs: dict) -> float:
        """How much of ``arm``'s part in this phase is still to do (m): its distance to its target beyond the
        tolerance, plus :data:`EVENT_M` when the phase's grasp or release is its own."""
        p = self.phase
        left = EVENT_M if (p.holds[arm] != p.then[arm]) else 0.0
        goal = self.target(arm, raw_obs)
        if goal is not None:
            tip = np.asarray(raw_obs["observation"][7 * arm:7 * arm + 3], np.float64)
            left += max(float(np.linalg.norm(goal[0] - tip)) - goal[1], 0.0)
        return left

    def may_start(self, operator, index: int) -> bool:
        """A :class:`~surrol_data.collect.operator.operator.Team`-like gate for an operator driving one arm while
        the policy drives the other: step ``index`` starts once the scene has reached its phase, or the other arm
        holds the object as the plan has it hold then (it grasped before a hand-over, or let go before this arm
        carries on). The arm's own grasp does not hold its next step back."""
        phase = next(k for k, p in enumerate(self.phases) if p.first <= index <= p.last)
        if phase <= self.index:
            return True
        other = 1 - operator.arm
        return bool(self.env.grasps[other].attached) == self.phases[phase].holds[other]

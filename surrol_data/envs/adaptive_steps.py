"""Adaptive sub-stepping: fine physics steps only while something moves fast near something it can hit.

PyBullet resolves a contact only after bodies already overlap, so a body moving ``v`` per second sinks up to
``v × dt`` into whatever it meets within one physics step of ``dt``. Tool tips (up to ~14 cm/s at full action)
and dropped objects (~0.5 m/s after 60 mm) sink millimetres at the coarse step, which is fine everywhere else.
Before each coarse step the planner estimates how far the fastest tool near another body, and the fastest
object, could travel; the coarse step is split into as many fine steps as keep that travel under
``physics.MAX_TRAVEL_PER_STEP_M`` (at most ``physics.MAX_REFINEMENT``). The test costs a few PyBullet queries
(~10 µs) per coarse step; the fine steps cost only where they are needed.
"""

from __future__ import annotations

import math

from surrol_data.envs import physics
from surrol_data.envs.units import SCALING

# Tool links whose sweep matters (wrist pitch link, both jaws).
_TOOL_LINKS = (4, 6, 7)


class SubstepPlanner:
    def __init__(self, client, grasps, dynamic_bodies):
        """``grasps``: each arm's grasp (its ``psm`` and what it holds); ``dynamic_bodies``: a callable returning
        the scene's movable object ids."""
        self.client = client
        self.grasps = grasps
        self.dynamic_bodies = dynamic_bodies
        self.refined_steps = 0     # coarse steps that were split (for benchmarks)

    def refinement(self, dt: float) -> int:
        """How many fine steps the next coarse step of ``dt`` seconds needs (1 = none)."""
        travel = max(self._object_travel(dt), self._tool_travel(dt))
        k = min(physics.MAX_REFINEMENT, math.ceil(travel / physics.MAX_TRAVEL_PER_STEP_M - 1e-9))
        if k > 1:
            self.refined_steps += 1
        return max(k, 1)

    def _object_travel(self, dt: float) -> float:
        """Travel of the fastest object that could hit something other than a tool (tool hits are the tools')."""
        c = self.client
        worst = 0.0
        tools = {g.psm.body for g in self.grasps}
        for body in self.dynamic_bodies():
            v = c.getBaseVelocity(body)[0]
            travel = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) / SCALING * dt
            if travel <= max(worst, physics.MAX_TRAVEL_PER_STEP_M):
                continue
            if self._near_other_body(body, (-1,), travel * SCALING, ignore=tools):
                worst = travel
        return worst

    def _tool_travel(self, dt: float) -> float:
        c = self.client
        worst = 0.0
        for grasp in self.grasps:
            psm = grasp.psm
            # A motor held back (the tool pressed on an object that may give way) can reach its speed limit
            # within the step: the bound takes the faster of the current speed and that.
            travel = psm.blade_speed_bound(dt) * dt
            if travel <= max(worst, physics.MAX_TRAVEL_PER_STEP_M):
                continue
            # A held object moves with the tool (the object test watches what it may hit).
            held = (grasp.object_id,) if grasp.attached else ()
            if not self._near_other_body(psm.body, _TOOL_LINKS, travel * SCALING, ignore=held):
                continue
            worst = max(worst, travel)
        return worst

    def _near_other_body(self, body: int, links, reach: float, ignore=()) -> bool:
        """Does the bounding box of ``body``'s ``links``, grown by ``reach``, overlap any other body's?"""
        c = self.client
        lo, hi = [math.inf] * 3, [-math.inf] * 3
        for link in links:
            a, b = c.getAABB(body, link)
            lo = [min(x, y) for x, y in zip(lo, a)]
            hi = [max(x, y) for x, y in zip(hi, b)]
        lo = [x - reach for x in lo]
        hi = [x + reach for x in hi]
        return any(other != body and other not in ignore for other, _ in (c.getOverlappingObjects(lo, hi) or ()))

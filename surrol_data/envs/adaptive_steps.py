"""Adaptive sub-stepping: fine physics steps only while something moves fast near something it can hit.

PyBullet resolves a contact only after bodies already overlap, so a body moving ``v`` per second sinks up to
``v × dt`` into whatever it meets within one physics step of ``dt``. Tool tips (up to ~14 cm/s at full action)
and dropped objects (~0.5 m/s after 60 mm) sink millimetres at the coarse step, which is fine everywhere else.
Once per control period the planner bounds how fast the tools' blades may move (their ramped joint targets
are known) and, if one could come near another body meanwhile, how finely to step; before each coarse step
it checks the objects' speeds (a dropped object speeds up within the period). A coarse step is split into as
many fine steps as keep that travel under ``physics.MAX_TRAVEL_PER_STEP_M`` (tools) or
``physics.MAX_OBJECT_TRAVEL_PER_STEP_M`` (objects; a scene may set its own), at most ``physics.MAX_REFINEMENT``.
The tests cost a few PyBullet queries per step; the fine steps cost only where they are needed.

A closing jaw whose blades are near the object it may grip is refined too, so that between two of the grasp's
checks (one per physics step) a blade cannot pass through more than the touch distance
(``physics.GRASP_CONTACT_DISTANCE_M``) into the object: at the coarse step a blade closing at full speed, on an
object its partner pushes towards it, covered ~1.1 mm per step, and the grip froze it 0.45 mm inside the block
(benchmarks/physics_realism.py, BiPegTransfer's oracle).
"""

from __future__ import annotations

import math

from surrol_data.envs import physics
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import EEF_LINK, HAND_LINKS, JAW_JOINTS
from surrol_data.envs.tool_sweep import ToolSweep
from surrol_data.envs.units import SCALING

_GRAVITY = abs(physics.GRAVITY[2])
_base_velocity = pb.getBaseVelocity
# Refine a tool's period only for bodies it moves towards fast enough to reach (tool_sweep.py); False: for every
# body within its reach, whichever way it moves (the test before, kept to measure against).
DIRECTIONAL_TOOL_TEST = True
# Leave an object out of the per-step speed checks for a period in which the tool holding it is too slow to make it
# fast (see SubstepPlanner._tool_travel); False: check every object at every coarse step.
SKIP_SLOW_HELD_OBJECTS = True
# Carry a welded object kinematically (grasp.py, 6. Carry) for a control period in which nothing but its hand can
# come near it, in the envs that ask for it (``carry=True``); False: always by the weld.
CARRY_CLEAR_HELD_OBJECTS = True
# What a carried object keeps clear of everything else over the period, beyond the most its hand may move it
# (real metres): the weld is back before anything comes nearer than this. A margin, not a tuned value: twice the
# contact-overlap target; the oracle's gauze is 2.8 mm over the floor after its first welded step (it is carried
# from the next), and a carried gauze driven into the tray at full speed is back on its weld in time to end as deep
# as one never carried (tests/test_kinematic_carry.py).
CARRY_CLEARANCE_M = 0.002
# Move an arm whose object is carried and which touches nothing over the period by its motors' closed-form rule
# (free_motion.py) instead of PyBullet's steps; False: always PyBullet's.
FREE_ARM_MOTION = True
# A held object pressed on a static body is stepped finely enough that what presses it could drive it in by no more
# than an object's travel limit within a physics step in which the contact is lost (SubstepPlanner.
# _pressed_hold_refinement). GauzeRetrieve's gauze held down on the tray floor sank 1.25–1.35 mm into it in such a step
# at the coarse step, ≤ 0.17 mm refined (benchmarks/physics_realism.py held-press, seeds 0–2); the gauze as a hull
# instead, whose contacts come before it overlaps, tumbled for seconds after a drop where a box comes to rest at once.
# Tool links whose sweep matters (wrist pitch link, both jaws).
_TOOL_LINKS = (4, 6, 7)
_COLLIDING_LINKS = HAND_LINKS + JAW_JOINTS
# Spin (rad/s) below which an object's far points move no faster than its centre, to within the travel limits.
_SPIN_NEGLIGIBLE_RAD_S = 0.01


class SubstepPlanner:
    def __init__(self, client, grasps, dynamic_bodies, carry: bool = False,
                 object_travel_m: float = physics.MAX_OBJECT_TRAVEL_PER_STEP_M):
        """``grasps``: each arm's grasp (its ``psm`` and what it holds); ``dynamic_bodies``: a callable returning
        the scene's movable object ids; ``carry``: a single arm's welded object may be carried kinematically while
        nothing can come near it (``CARRY_CLEAR_HELD_OBJECTS``); ``object_travel_m``: the most a fast object near
        another body may travel per physics step (real metres; the scene's objects' limit, see physics.py)."""
        self.carry = carry and len(grasps) == 1
        self.object_travel_m = object_travel_m
        self.client = client
        self.grasps = grasps
        self.dynamic_bodies = dynamic_bodies
        self._cid = client._client
        self._tool_k = 1
        self._bodies: list[int] = []
        self._closing: list = []   # grasps whose jaws close this control period and hold nothing yet
        self._slow_held: set[int] = set()
        self._motion: dict = {}    # per period: each tool's joint states, speed bound and sweep (see _tool_motion)
        self._pressed: dict = {}   # grasp → refinement its held object's press asked for at this period's start
        self.carried: list = []    # grasps whose objects are carried kinematically this period
        self.free_arm = None       # the grasp whose arm touches nothing while nothing else moves, this period
        self.refined_steps = 0     # coarse steps that were split (for benchmarks)
        self.carried_periods = 0   # control periods with a carried object (for benchmarks)
        self.free_periods = 0      # control periods moved in closed form (counted by the env, for benchmarks)

    def plan_tools(self, dt: float, closing=()) -> None:
        """Once per control period, before its physics steps: the refinement the tools' moves need. Their speed
        during the period is set by the ramped joint targets (known now), so one test per period suffices.
        ``closing``: the grasps whose jaws close during the period without holding anything yet."""
        self._slow_held = set()
        self._motion = {}
        if self.carry:
            self._plan_carry(dt)
        self._tool_k = self._k(self._tool_travel(dt), physics.MAX_TRAVEL_PER_STEP_M)
        bodies = self.dynamic_bodies()
        pressed = self._pressed_hold_refinement(bodies, dt)
        if pressed > self._tool_k:
            self._tool_k = pressed
        if self.carried:
            # A carried object touches nothing this period: no speed checks (it moves with the wrist exactly).
            self._slow_held.update(g.object_id for g in self.carried)
        if self._slow_held and bodies:
            bodies = [b for b in bodies if b not in self._slow_held]
        self._bodies = bodies
        self._closing = [g for g in closing if g.object_id >= 0]
        self.free_arm = None
        # Nothing else moves (the arm carries every object there is) and nothing can touch the arm.
        if FREE_ARM_MOTION and self.carried and not bodies and not self._closing and self._tool_k == 1:
            grasp = self.carried[0]   # (a carry has a single arm)
            if self._tool_clear(grasp, dt):
                self.free_arm = grasp

    def _pressed_hold_refinement(self, bodies, dt: float) -> int:
        """The refinement a held object (by a weld or grip, not carried) pressed on a static body needs: pressed there by
        a stalled arm, it loses that contact for a physics step whenever it rises off it by a hair (Bullet's box-box
        test reports boxes only once they overlap), and what pressed it then drives it in within the step, by up to
        its contacts' push beyond its weight over the mass driven (its own and the arm's) times the step squared (at
        the last physics step's contact forces). Split so that this stays within the objects' travel limit; 1 when
        nothing presses."""
        k, movable, cid = 1, None, self._cid
        pressed = self._pressed
        self._pressed = {}
        for grasp in self.grasps:
            if grasp.constraint is None or grasp.carried or grasp.object_link >= 0:
                continue
            if movable is None:
                movable = set(bodies).union(g.psm.body for g in self.grasps)
            obj = grasp.object_id
            force = 0.0
            for p in pb.getContactPoints(obj, -1, -2, -2, cid):   # (positional: faster)
                if (p[2] if p[1] == obj else p[1]) not in movable:
                    force += p[9]
            if force > 0.0:
                # (The object moves with the arm that holds it: both are driven, the links the insertion carries.)
                mass = pb.getDynamicsInfo(obj, -1, cid)[0]
                push = (force - mass * _GRAVITY) / (mass + grasp.psm.carried_lift[2] / _GRAVITY)   # scaled m/s²
                if push > 0.0:
                    self._pressed[grasp] = self._k(push * dt * dt / SCALING, self.object_travel_m)
            elif grasp in pressed:
                # Pressed at the last period's start and bounced off at its end: what pressed it presses it again
                # within this period (a MatchBoard block held down on the table went 1.04 mm in at a coarse step so).
                self._pressed[grasp] = 1
                k = max(k, pressed[grasp])
            k = max(k, self._pressed.get(grasp, 1))
        return k

    def _plan_carry(self, dt: float) -> None:
        """Carry a welded object for the period if nothing but its hand's blades can come within the period's reach
        of it (the most its hand may move it, plus ``CARRY_CLEARANCE_M``); else have it held by the weld."""
        self.carried = []
        for grasp in self.grasps:
            if not CARRY_CLEAR_HELD_OBJECTS:
                grasp.restore()
                continue
            if grasp.constraint is None or not grasp.welded or grasp.passive or grasp.object_link >= 0:
                continue
            psm = grasp.psm
            states, bound = self._tool_motion(psm, dt)
            held = self._held_speed(grasp, dt, states, bound)
            reach = (held * dt * physics.SUBSTEPS + CARRY_CLEARANCE_M) * SCALING
            if self._clear(grasp, states, dt * physics.SUBSTEPS, reach):
                grasp.carry()
                grasp.plan_load()
                self.carried.append(grasp)
                self.carried_periods += 1
            else:
                grasp.restore()

    def _clear(self, grasp, states, period: float, reach: float) -> bool:
        """Can nothing come within ``CARRY_CLEARANCE_M`` of the held object within the period? ``reach`` (scaled):
        the most the hand may move it meanwhile, plus that clearance. A body within reach counts only if the object
        moves towards it fast enough to close the gap (less the clearance) within the period: the object is fixed to
        the wrist-yaw link, so the tool's sweep bounds its motion as it bounds a blade's (tool_sweep.py). Without
        the direction, GauzeRetrieve's lifted gauze, moving up and away from the tray floor, stayed on the weld for
        6 more steps per episode (seeds 0–1), a third of the steps it is held."""
        body, psm = grasp.object_id, grasp.psm
        candidates, boxes = self._candidates(body, (-1,), reach, ignore={psm.body})
        clearance = CARRY_CLEARANCE_M * SCALING
        # (The sweep is built only when a point within reach asks for it: mostly none does.)
        # The hand's own colliding links (the shaft on link 3, the wrist on link 4; the blades do not collide with
        # what they hold) move relative to the object only by the wrist joints between them and the wrist-yaw link.
        for p in pb.getClosestPoints(body, psm.body, reach, physicsClientId=self._cid):
            link = p[4]
            if link in JAW_JOINTS:
                continue
            if link not in HAND_LINKS:   # (they turn relative to the wrist-yaw link by wrist joints only)
                return False
            turn = self._sweep(psm, states, period).turn_reach(range(link + 1, EEF_LINK + 1), boxes[0])
            if p[8] - clearance <= turn:
                return False
        for other in candidates:
            for p in pb.getClosestPoints(body, other, reach, physicsClientId=self._cid):
                # (p[7]: the normal from the other body to the object; ``may_close`` takes the object as a part of
                # the wrist-yaw link, its bounding box for the link's.)
                if self._sweep(psm, states, period).may_close(EEF_LINK, p[7], p[8] - clearance, boxes[0]):
                    return False
        return True

    def _tool_clear(self, grasp, dt: float) -> bool:
        """Can none of the tool's colliding links come within ``CARRY_CLEARANCE_M`` of another body (but the object
        it carries, which they do not collide with) over the period? Then no contact acts on the arm: PyBullet
        makes a contact's constraint only of a pair within a step's reach of touching."""
        psm = grasp.psm
        bound = self._tool_motion(psm, dt)[1]
        reach = (bound * dt * physics.SUBSTEPS + CARRY_CLEARANCE_M) * SCALING
        return not self._near_other_body(psm.body, _COLLIDING_LINKS, reach, ignore={grasp.object_id})

    def joint_states(self, psm, dt: float) -> tuple:
        """PyBullet's states of a tool's joints 0–7 this period (read once: see _tool_motion)."""
        return self._tool_motion(psm, dt)[0]

    def _tool_motion(self, psm, dt: float) -> tuple:
        """(joint states, blade speed bound) of a tool for this period, asked for once (the carry and the tools'
        tests both need them; nothing moves the joints in between)."""
        key = (psm, dt)
        motion = self._motion.get(key)
        if motion is None:
            states = psm.moving_joint_states()
            motion = self._motion[key] = (states, psm.blade_speed_bound(dt, states))
        return motion

    def _held_speed(self, grasp, dt: float, states, bound: float) -> float:
        """The bound on the held object's speed this period (Psm.held_speed_bound), asked for once: the carry and the
        slow-held test both need it, and neither the joints nor where the object sits in the hand change between."""
        key = (grasp, "held")
        held = self._motion.get(key)
        if held is None:
            held = self._motion[key] = grasp.psm.held_speed_bound(dt, grasp.held_offset_m(), states, bound)
        return held

    def _sweep(self, psm, states, period: float) -> ToolSweep:
        """The tool's sweep over this period, built once (see _tool_motion)."""
        key = (psm, "sweep")
        sweep = self._motion.get(key)
        if sweep is None:
            sweep = self._motion[key] = ToolSweep(psm, states, period)
        return sweep

    def steady_refinement(self, steps: int) -> int | None:
        """The refinement of each of the period's ``steps`` coarse steps when nothing needs a look before each (no
        object to watch, no jaw closing on one): the tools' alone, counted for all of them at once; None
        otherwise (then ask :meth:`refinement` before each)."""
        if self._bodies or self._closing:
            return None
        if self._tool_k > 1:
            self.refined_steps += steps
        return self._tool_k

    def refinement(self, dt: float) -> int:
        """How many fine steps the next coarse step of ``dt`` seconds needs (1 = none)."""
        k = self._tool_k
        travel = self._object_travel(dt) if self._bodies else 0.0
        if travel:
            k = max(k, self._k(travel, self.object_travel_m))
        if self._closing:
            travel = self._jaw_travel(dt)
            if travel:
                k = max(k, self._k(travel, physics.GRASP_CONTACT_DISTANCE_M))
        if k > 1:
            self.refined_steps += 1
        return k

    @staticmethod
    def _k(travel: float, limit: float) -> int:
        return max(1, min(physics.MAX_REFINEMENT, math.ceil(travel / limit - 1e-9)))

    def _object_travel(self, dt: float) -> float:
        """Travel of the fastest object that could hit something other than a tool (tool hits are the tools')."""
        worst = 0.0
        limit = self.object_travel_m * SCALING / dt   # scaled speed below which nothing matters
        fall = _GRAVITY * dt
        cid = self._cid
        for body in self._bodies:
            v, w = _base_velocity(body, cid)   # (positional: PyBullet's keyword parsing costs more than the call)
            speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + (fall if v[2] < -fall else 0.0)
            # (Falling objects speed up within the step by what gravity gives them meanwhile.)
            spin = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
            if spin > _SPIN_NEGLIGIBLE_RAD_S:
                # A tumbling object's far points move faster than its centre of mass: a needle flicked by a poke
                # spun at 18 rad/s and its end, at 3× the centre's speed, sank 1.4 mm into the pad on landing.
                speed += spin * self._reach(body)
            if speed <= limit:
                continue
            travel = speed / SCALING * dt
            if travel > worst and self._near_other_body(body, (-1,), travel * SCALING,
                                                        ignore={g.psm.body for g in self.grasps}):
                worst = travel
        return worst

    def _reach(self, body: int) -> float:
        """A bound (scaled) on the distance from ``body``'s centre of mass to any of its points: its bounding box
        lies within the sphere of its half-diagonal about the box's centre. (Asked only of spinning objects.)"""
        lo, hi = pb.getAABB(body, -1, self._cid)
        centre = [(a + b) / 2 for a, b in zip(lo, hi)]
        com = pb.getBasePositionAndOrientation(body, self._cid)[0]
        return math.dist(centre, com) + math.dist(lo, hi) / 2

    def _jaw_travel(self, dt: float) -> float:
        """How far (real metres) a closing blade may come towards its object within a step of ``dt``, if some
        closing jaw's blades are that near it (0 otherwise): the blade at the jaw's speed limit, and the object
        pushed towards it by the other blade as fast."""
        travel = 2.0 * physics.JAW_MAX_VELOCITY * physics.BLADE_LENGTH_M * dt
        self._closing = [g for g in self._closing if not g.attached]
        cid = self._cid
        for grasp in self._closing:
            if grasp.psm.jaw_angle() < physics.GRASP_MIN_OPENING_RAD:
                continue   # a closed jaw grips nothing (see Grasp.between_blades)
            body = grasp.psm.body
            for link in JAW_JOINTS:
                if pb.getClosestPoints(body, grasp.object_id, travel * SCALING, link, grasp.object_link,
                                       physicsClientId=cid):
                    return travel
        return 0.0

    def _tool_travel(self, dt: float) -> float:
        """The worst per-step travel of a tool that may reach another body this period (0 if none). Notes, on
        the way, the held objects whose tools are too slow to make them fast (``_slow_held``): they move with the
        wrist (the grasp's constraint holds them against far more than their weight), so the per-step speed
        checks would find them slow, and they are left out of those checks for the period."""
        worst = 0.0
        for grasp in self.grasps:
            psm = grasp.psm
            states, bound = self._tool_motion(psm, dt)
            travel = bound * dt
            if SKIP_SLOW_HELD_OBJECTS and grasp.attached and grasp.object_link < 0:
                held = self._held_speed(grasp, dt, states, bound)
                if held * dt <= self.object_travel_m:
                    self._slow_held.add(grasp.object_id)
            if travel <= max(worst, physics.MAX_TRAVEL_PER_STEP_M):
                continue
            # A held object moves with the tool (the object test watches what it may hit). The reach covers the
            # whole control period's move; within it, only a body the tool moves towards fast enough to close
            # the gap counts (tool_sweep.py).
            held = (grasp.object_id,) if grasp.attached else ()
            reach = travel * SCALING * physics.SUBSTEPS
            if DIRECTIONAL_TOOL_TEST:
                near = self._tool_may_reach(psm, states, dt * physics.SUBSTEPS, reach, held)
            else:
                near = self._near_other_body(psm.body, _TOOL_LINKS, reach, ignore=held)
            if near:
                worst = travel
        return worst

    def _candidates(self, body: int, links, reach: float, ignore=()) -> tuple[list, list]:
        """Bodies whose bounding boxes come within ``reach`` (scaled) of ``body``'s ``links``' (PyBullet's boxes
        include a collision margin of ~8 mm real, so they overlap near every floor), and the links' boxes."""
        cid = self._cid
        boxes = [pb.getAABB(body, link, cid) for link in links]
        if len(boxes) == 1:
            lo, hi = boxes[0]
        else:
            lows, highs = zip(*boxes)
            lo, hi = [min(x) for x in zip(*lows)], [max(x) for x in zip(*highs)]
        found = pb.getOverlappingObjects([x - reach for x in lo], [x + reach for x in hi], cid)
        candidates = {other for other, _ in (found or ())}
        candidates.discard(body)
        candidates.difference_update(ignore)
        return sorted(candidates), boxes

    def _near_other_body(self, body: int, links, reach: float, ignore=()) -> bool:
        """Is another body within ``reach`` (scaled) of ``body``'s ``links``? Bounding boxes first, then exact
        distances."""
        candidates, _ = self._candidates(body, links, reach, ignore)
        for other in candidates:
            # (One query for all of the body's links, the points of the links asked for kept.)
            for p in pb.getClosestPoints(body, other, reach, physicsClientId=self._cid):
                if p[3] in links:
                    return True
        return False

    def _tool_may_reach(self, psm, states, period: float, reach: float, ignore=()) -> bool:
        """Can the tool's links reach another body within the period (``reach``: the most any blade point may
        travel meanwhile, scaled)? Exact distances to the bodies within reach, then whether the tool moves
        towards each closest point fast enough to close its gap (tool_sweep.py)."""
        body = psm.body
        candidates, boxes = self._candidates(body, _TOOL_LINKS, reach, ignore)
        boxes = dict(zip(_TOOL_LINKS, boxes))
        sweep = None
        for other in candidates:
            # One query for all the tool's links (the shaft's points are left out: it is not a link watched).
            # A compound body gives one point per child shape: each is a convex pair of its own.
            for p in pb.getClosestPoints(body, other, reach, physicsClientId=self._cid):
                link = p[3]
                if link not in boxes:
                    continue
                if sweep is None:
                    sweep = self._sweep(psm, states, period)
                if sweep.may_close(link, p[7], p[8], boxes[link]):
                    return True
        return False

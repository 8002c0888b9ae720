"""Grasping as on the instrument: the object must lie between the blades, and a weld that can break.

1. **Squeeze.** While the jaw closes, the blades collide with the object and stop on it, so the jaw angle
   reads the object's width.
2. **Grip.** Once both blades touch the object *on their inner faces* (contact normal across the closing gap,
   contact point along the blade, not past its end), from outside it (``physics.GRASP_MAX_BLADE_DEPTH_M``), with
   the two contact normals opposed (the object across the gap: a tip-pinch on two faces ~90° apart is not a grasp)
   and the jaw still open by more than the thinnest object leaves it, the object is fixed to the wrist at the pose
   it has in
   the hand by a constraint as strong as the squeeze's friction (``physics.GRASP_FRICTION_FORCE``), and each
   blade is held where it stopped (``Psm.hold_blades``: a jaw that met the object off its centre line stays
   turned). A closing jaw near the object is sub-stepped finely enough that no blade passes more than the touch
   distance into it between two checks (adaptive_steps.py). A closed jaw poked onto an object or swiped into it
   touches it with a blade's end or outer face and never grips.
3. **Weld.** Once the task's lift condition holds (the reference's ``_meet_contact_constraint_requirement``:
   e.g. the needle lifted 5 mm), the constraint gets the weld's full force (``physics.GRASP_MAX_FORCE``).
   The reference lifts by the friction of its squeezing jaws until then; PyBullet's contacts at our step
   size are too soft to squeeze without the blades closing through the object, so the grip stands in for
   that friction. While gripped or welded, each blade is held where it stopped (the jaw cannot close
   through the object), and the blades stop colliding with the held object:
   their contacts would only fight the weld (a block held by two hands gets twisted out of the second hand
   once the first lets go) and would make carrying cost 2–3× the physics of a free move.
4. **Drop.** The constraint's force is bounded (``physics.GRASP_MAX_FORCE``); pulled harder (the object caught on
   a peg, pushed into the board), the object slips in the hand, and past ``physics.GRASP_MAX_SLIP_M`` it is
   dropped: the weld goes, the jaw closes, ``drops`` counts it; checked after every physics step (``gives``), as is
   a held object pressed into a static body past ``physics.GRASP_MAX_PRESS_M``, which slips out the same way.
   Opening the jaw releases.
5. **Hand-over.** One constraint at a time drives an object. A jaw that closes on an object another arm's grasp
   (a ``peer``) already holds stops on it as in 2 and holds it *by its blades alone*: no constraint, and its blades
   keep colliding with the object, so it is squeezed and pushed by real contacts (``passive``; it counts as holding).
   When the holding peer lets go (opens, or drops it), the squeezing hand takes the object where it now sits between
   its blades (its own constraint, as in 2–3), before the next physics step. Two welds on one object make a rigid
   loop through both force-limited arms, whose pull can then only go into the welds' give, i.e. into blades that
   no longer collide with the object; with one weld the receiving hand gives as a hand does (its blades slide on
   the object or are pried open). A squeezing hand pulled off the object (it slips past
   ``physics.GRASP_MAX_SLIP_M`` between its blades) has lost it, as in 4. (BiPegTransfer's oracle read 1.4 mm of
   blade inside the block at its hand-over; most of it came from the grip itself, see 2 and the blade hold, and
   with those fixed one weld or two both read ≤ 0.4 mm on the oracle: benchmarks/physics_realism.py, 5 episodes.)

6. **Carry.** A welded object that nothing but the holding hand can come near within the coming control period
   moves with the wrist exactly as the weld holds it (the weld's give is < 0.1 mm at a 50 g gauze), so for that
   period it may be carried kinematically instead (``carry``, chosen by adaptive_steps.SubstepPlanner where the
   env asks for it): the constraint is taken out of the solver, the object out of the dynamics (massless, still,
   not colliding with the hand) and put at its pose in the hand after the period's physics steps (after each of
   them while a probe looks: PsmEnv.substep_hook, without a forward-kinematics pass, see ``follow_seen``), and the
   wrist link carries the object's mass, inertia and weight instead, so the arm is loaded as before. The constraint comes back (``restore``) with the frame it was made with
   before any period in which something could come near the object, and before the grasp lets go; the object then
   rejoins the dynamics where the hand has it, moving with the wrist.
   Why: a JOINT_FIXED constraint on the arm makes every physics step cost ~1.7× (PyBullet's multibody constraint
   rows are rebuilt every step and the solver runs all its iterations: 62 vs 37 µs a step), and in GauzeRetrieve's
   oracle episodes two thirds of the steps carry the gauze, mostly in free space. While carried, the object is held
   (``attached``), its slip stays what it was (nothing but the weld's force limit could make it slip, and nothing
   pulls on it), and drops, release and the info are as before.
   Measured (GauzeRetrieve, the only task that asks for it so far: PsmEnv.KINEMATIC_CARRY): 30 of the ~34 held steps
   of an oracle episode carried, oracle steps/s ×1.19–1.22 (one process, 10 episodes × 5 rounds alternating on and
   off, medians; three such runs); tip and gauze within 0.05 mm of the welded episode's at every step (seeds 0–4:
   what remains is the weld's give, which the carry does not have). The load on the wrist link is what the weld
   passed on to the arm (the 50 g gauze weighs 17 of its links, half the insertion motor's force limit); the motors,
   stiff at these speeds, hardly feel it: without it the same probes (and bang-bang moves in free air, seeds 0–2)
   came out within 0.013 mm of with it. It is kept for moves where the limits bind, at one PyBullet call a step.
   Driven into the tray's floor or wall at full speed, the gauze ends as deep as on the weld (within 0.002 mm,
   seeds 0–2); benchmarks/physics_realism.py reads the same rows as without the carry (30 episodes).
   A carrying arm that nothing can touch over the period, the carried object being the only one, is moved by its
   motors' closed-form rule instead of PyBullet's steps (free_motion.py; within 2.5e-5 rad of PyBullet's own result).

PyBullet keys pair filters by body ids, which removed bodies hand on: envs release every grasp before they
respawn bodies.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from surrol_data.envs import physics
from surrol_data.envs.numeric import vector_norm
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import EEF_LINK, HAND_LINKS, JAW_JOINTS
from surrol_data.envs.units import SCALING

_TOUCH = physics.GRASP_CONTACT_DISTANCE_M * SCALING
_BLADE_LENGTH = physics.BLADE_LENGTH_M * SCALING
_ACROSS = np.cos(np.deg2rad(45.0))   # contact normal within 45° of the inner-face normal
_OPPOSED = np.cos(np.deg2rad(45.0))  # the two blades' contact normals within 45° of opposite
_MAX_DEPTH = physics.GRASP_MAX_BLADE_DEPTH_M * SCALING
_MAX_PRESS = physics.GRASP_MAX_PRESS_M * SCALING
# The slip (real metres) past which gives() looks for a blade inside the held object (see _blade_in): a slip of a step
# read at the step's start lags by a step's slip, so half of the depth a grip may leave, not all of it.
_BLADE_CHECK_SLIP = 0.5 * physics.GRASP_MAX_BLADE_DEPTH_M
_ORIGIN, _NO_TURN = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
_WORLD_FRAME = pb.WORLD_FRAME
# Direction from each blade towards the other, in the blade's link frame (blade 6 lies on +x, blade 7 on −x).
_TOWARDS_OTHER = (-1.0, 1.0)


class Grasp:
    def __init__(self, client, psm, object_id: int, lift_condition: Callable[[], bool] | None = None,
                 object_link: int = -1):
        self.client = client
        self.psm = psm
        self.object_id = object_id
        self.object_link = object_link   # -1: the object's base; else a link of it (a drawer's handle)
        self.max_slip_m = physics.GRASP_MAX_SLIP_M
        self.lift_condition = lift_condition or (lambda: True)
        self.constraint: int | None = None
        self.welded = False              # the full-strength weld (after the lift condition), not the grip
        self.passive = False             # squeezing an object a peer's constraint holds (see 5. Hand-over)
        self.drops = 0                   # welds lost to force or slip while the jaw stayed closed
        self.peers: tuple[Grasp, ...] = ()   # the other arms' grasps in the scene (bimanual envs)
        self._held_at: np.ndarray | None = None
        self.hold_serial = 0             # counts holds (grips, takes): a carry and its restore stay the same hold
        self.carried = False             # carried kinematically for this control period (see 6. Carry)
        self._frame = None               # (position, quaternion) in the wrist frame the constraint holds it at
        self._carry_at = None            # (position, quaternion) in the wrist frame while carried
        self._carry_load = None          # (object's mass, inertia, wrist link's mass, inertia) while carried
        self._torque = _ORIGIN           # the object's weight's moment about the wrist link's origin, while carried
        self._eef = None                 # the wrist link's frame when last asked for, while carried
        self._carry_slip = 0.0           # the slip (m) when the carry began: it stays so while carried

    @property
    def attached(self) -> bool:
        """Holding the object: by a constraint, or (``passive``) by the blades while a peer's constraint holds it."""
        return self.constraint is not None or self.passive

    def holds(self, object_id: int, object_link: int) -> bool:
        """Whether this grasp's constraint drives that object (what a peer closing on it must not double)."""
        return self.constraint is not None and self.object_id == object_id and self.object_link == object_link

    def between_blades(self) -> bool:
        """Both blades touch the object on their inner faces, within the blade length, from outside it, with contact
        normals opposed (the object lies across the gap between the faces), and the jaw is open
        (``physics.GRASP_MIN_OPENING_RAD``)."""
        if self.object_id < 0 or self.psm.jaw_angle() < physics.GRASP_MIN_OPENING_RAD:
            return False
        first = self._inner_face_normals(JAW_JOINTS[0], _TOWARDS_OTHER[0])
        if not first:
            return False
        second = self._inner_face_normals(JAW_JOINTS[1], _TOWARDS_OTHER[1])
        # A tip-pinch (the blade ends on two faces of a jack's arm ~90° apart) touches both inner faces within their
        # 45° cones but squeezes nothing between them: it lifted PickAndPlace's jacks by the weld (tests/
        # test_held_objects.py). The faces of a held object push the blades apart along one line.
        return any(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] < -_OPPOSED for a in first for b in second)

    def _inner_face_normals(self, link: int, towards_other: float) -> list:
        """The contact normals (world, object → blade) of the blade's inner-face touches of the object; none if the
        blade lies inside the object deeper than ``physics.GRASP_MAX_BLADE_DEPTH_M`` (a blade that closed through it,
        or one left in it by a drop, does not touch it from outside)."""
        # (Run after every physics step while a jaw closes: PyBullet called positionally where it can.)
        cid = self.client._client
        points = pb.getClosestPoints(self.psm.body, self.object_id, _TOUCH, link, physicsClientId=cid)
        if not points or min(p[8] for p in points) < -_MAX_DEPTH:
            return []
        state = pb.getLinkState(self.psm.body, link, 0, 1, cid)
        inv_pos, inv_quat = pb.invertTransform(state[4], state[5])
        normals = []
        for p in points:
            along = pb.multiplyTransforms(inv_pos, inv_quat, p[6], _NO_TURN)[0][1]
            normal_x = pb.multiplyTransforms(_ORIGIN, inv_quat, p[7], _NO_TURN)[0][0]
            # p[7] points from the object to the blade: for an inner-face touch, away from the other blade.
            if -towards_other * normal_x > _ACROSS and -_TOUCH <= along <= _BLADE_LENGTH:
                normals.append(p[7])
        return normals

    def held_offset_m(self) -> float:
        """How far (real metres) the held object's frame sits from the wrist's origin, at most: where it was
        gripped plus the slip allowed before it is dropped (0 when nothing is held)."""
        if self._held_at is None:
            return 0.0
        return float(vector_norm(self._held_at)) / SCALING + self.max_slip_m

    @property
    def held_at(self) -> np.ndarray | None:
        """Where (scaled, in the wrist-yaw link's frame) the held object sat when this hold began; None if none."""
        return self._held_at

    def slip_m(self) -> float:
        """How far (real metres) the held object has moved in the hand since the weld formed."""
        if self._held_at is None:
            return 0.0
        if self.carried:
            # Where ``follow`` keeps it: at its pose in the hand when the carry began (see 6. Carry).
            return self._carry_slip
        return float(vector_norm(self._relative_position() - self._held_at)) / SCALING

    def grip_if_between(self) -> bool:
        """Called after every physics substep while the jaw closes: grip the moment both blades touch the
        object's sides. Checked per substep because a closing jaw crosses a 1.2 mm wire within one control
        step, and the blades must stop where they meet it (PyBullet's contacts alone let the arm's motors push
        a blade into the wire by a millimetre or more). Returns whether the object is now held."""
        if not self.attached and self.between_blades():
            self._grip()
        return self.attached

    def gives(self, movable, dt: float) -> bool:
        """Called after every physics step while holding (not while carried: nothing makes a carried object slip nor
        presses it into anything): the grasp gives, and the drop is counted, if the object has slipped past
        ``max_slip_m`` in the hand or is pressed into a static body (anything not in ``movable``: the scene's objects
        and the arms) deeper than ``physics.GRASP_MAX_PRESS_M``. Returns whether it was dropped. ``dt``: the physics
        step just taken.

        Checked once per control step, a block slipped 5.15 mm in the middle of a step and was back within 0.26 mm at
        its end, never counted (BiPegTransfer, bang-bang). Held by the weld, whose force limit is ten times what the
        arm pushes with, an object pushed down on its board went into it instead of slipping in the hand (a block
        1.32 mm into MatchBoard's board, a gauze 1.35 mm into its tray: PyBullet's solver does not resolve the chain
        of motor, weld and contacts; 150 solver iterations mended the gauze but not the block, a weld as weak as the
        grip the block but not the gauze).

        Not only while the object touches something: touching nothing (at that step nor the one before), a welded
        needle or ring slipped by up to 1.05 mm within one physics step, to 1.74 mm (PegBoard, NeedleRegrasp,
        NeedleRings oracle, 5 episodes each), so a check skipped then could miss a slip past the limit."""
        if self.carried:
            return False
        slip = self._slip_now(dt)
        if slip > self.max_slip_m or (slip > _BLADE_CHECK_SLIP and self._blade_in()) or self._pressed_in(movable):
            self.drops += 1
            self.release()
            return True
        return False

    def _slip_now(self, dt: float) -> float:
        """The slip at the start of the physics step just taken (``dt`` seconds), read without a forward-kinematics pass
        (a third of this check's cost): the object in blade 6's frame (a link with a collision shape), compared with
        where it was gripped turned by the blade's joint (the blade turns about the wrist-yaw link's z, through its
        origin). PyBullet's stored link frames, read without that pass, are those the step began with (the colliders
        and the joints are at its end), so the object is taken where it was then: a body's position after a step is
        its position before plus its new velocity times the step. Compared with where it is now, a welded needle
        whipped round by bang-bang input read up to 1.95 mm more than its slip (0.12 mm) and was dropped
        (NeedlePick seed 2). The slip at a step's end is read after the next one, or by ``update`` at the period's
        end. Run after every physics step while holding, hence the plain arithmetic: no frame composed or inverted,
        math not numpy for scalars."""
        cid = self.client._client
        body = self.psm.body
        blade = pb.getLinkState(body, JAW_JOINTS[0], 0, 0, cid)
        angle = pb.getJointState(body, JAW_JOINTS[0], cid)[0]
        if self.object_link < 0:
            now = pb.getBasePositionAndOrientation(self.object_id, cid)[0]
            v = pb.getBaseVelocity(self.object_id, cid)[0]
            obj = (now[0] - v[0] * dt, now[1] - v[1] * dt, now[2] - v[2] * dt)
        else:   # (a drawer's handle: a link with a collision shape, whose stored frame is the step's start too)
            obj = pb.getLinkState(self.object_id, self.object_link, 0, 0, cid)[0]
        origin, (qx, qy, qz, qw) = blade[4], blade[5]
        # The object in the blade's frame: its offset from the shared origin turned back by the blade's orientation.
        rel = pb.multiplyTransforms(_ORIGIN, (-qx, -qy, -qz, qw),
                                    (obj[0] - origin[0], obj[1] - origin[1], obj[2] - origin[2]), _NO_TURN)[0]
        # The wrist's frame is the blade's turned by −angle about z, so the grip point in the blade's frame is the
        # one in the wrist's turned by −angle. (The jaw angle is held by the blade stops: its start-of-step value.)
        c, s = math.cos(angle), math.sin(angle)
        hx, hy, hz = self._held_at.tolist()
        return math.sqrt((rel[0] - c * hx - s * hy) ** 2 + (rel[1] + s * hx - c * hy) ** 2
                         + (rel[2] - hz) ** 2) / SCALING

    def _blade_in(self) -> bool:
        """A blade of this hand lies inside the held object deeper than ``physics.GRASP_MAX_PRESS_M``: the object has
        slipped across the gap into it (the blades do not collide with what they hold, so nothing else stops it). The
        hand has lost it, as an object slipped past the limit (a needle gripped after a drop and pressed on the pad slid
        1.87 mm in the hand, within the slip limit, and a blade stood 1.24 mm inside it: tests/test_held_objects.py).
        Asked only once the slip passes ``_BLADE_CHECK_SLIP``: a grip leaves each blade at most
        ``physics.GRASP_MAX_BLADE_DEPTH_M`` inside, and only a slip takes it deeper."""
        cid, body, obj, link = self.client._client, self.psm.body, self.object_id, self.object_link
        for blade in JAW_JOINTS:
            for p in pb.getClosestPoints(body, obj, 0.0, blade, link, physicsClientId=cid):
                if p[8] < -_MAX_PRESS:
                    return True
        return False

    def _pressed_in(self, movable) -> bool:
        """The held object (not a link: a drawer's handle is part of its cabinet) overlaps a static body deeper than
        ``physics.GRASP_MAX_PRESS_M`` at one of its contacts (as the last physics step's collision pass found them)."""
        if self.object_link >= 0:
            return False
        obj = self.object_id
        for p in pb.getContactPoints(obj, -1, -2, -2, self.client._client):   # (positional: faster)
            if p[8] < -_MAX_PRESS and (p[2] if p[1] == obj else p[1]) not in movable:
                return True
        return False

    def update(self, closing: bool) -> None:
        if not closing:
            self.release()
        elif not self.attached:
            if self.between_blades():
                self._grip()
        elif self.slip_m() > self.max_slip_m:
            self.drops += 1
            self.release()
        elif self.passive:
            if not self._held_by_peer():   # (a peer's release hands over at once; this is the fallback)
                self._take()
        elif not self.welded and self.lift_condition():
            self.client.changeConstraint(self.constraint, maxForce=physics.GRASP_MAX_FORCE)
            self.welded = True

    # ------------------------------------------------------------------ 6. Carry
    def carry(self) -> None:
        """Carry the welded object kinematically from now on (see 6. Carry), at its present pose in the hand."""
        if self.carried or self.constraint is None or not self.welded or self.passive or self.object_link >= 0:
            return
        c, cid, body, obj = self.client, self.client._client, self.psm.body, self.object_id
        self._eef, self._carry_at = self._wrist_and_relative_pose()
        self._carry_slip = float(vector_norm(np.asarray(self._carry_at[0]) - self._held_at)) / SCALING
        pb.removeConstraint(self.constraint, physicsClientId=cid)
        self.carried = True
        info = pb.getDynamicsInfo(obj, -1, physicsClientId=cid)
        link = pb.getDynamicsInfo(body, EEF_LINK, physicsClientId=cid)
        mass, own = info[0], np.asarray(info[2])
        # The wrist link takes the object's mass and its inertia about the link's origin (its own about its centre,
        # turned into the link frame, plus the parallel-axis term; PyBullet keeps a diagonal, so the products of
        # inertia are left out), so the force-limited motors accelerate what they accelerated through the weld.
        # (PyBullet reports a base's pose at its inertial frame, whose axes are the principal ones.)
        r = np.asarray(self._carry_at[0])
        turn = np.asarray(pb.getMatrixFromQuaternion(self._carry_at[1])).reshape(3, 3)
        inertia = np.diag(turn @ np.diag(own) @ turn.T) + mass * (r @ r - r * r)
        self._carry_load = (mass, tuple(info[2]), link[0], tuple(link[2]))
        c.changeDynamics(body, EEF_LINK, mass=link[0] + mass,
                         localInertiaDiagonal=(np.asarray(link[2]) + inertia).tolist())
        # The object itself leaves the dynamics: massless and still, it is neither pulled by gravity nor moved by the
        # solver; ``follow`` puts it where the hand has it.
        c.changeDynamics(obj, -1, mass=0.0)
        pb.resetBaseVelocity(obj, _ORIGIN, _ORIGIN, cid)
        self._set_collisions(HAND_LINKS, False)

    def plan_load(self) -> None:
        """Once per control period while carried: the moment that puts the object's weight, which acts on the mass
        added at the wrist link's origin, where the object's centre is (its offset turns with the wrist by
        little within a period, as the arm's own gravity compensation assumes: Psm.plan_gravity_compensation)."""
        # (The wrist's frame as ``carry`` or the last ``follow`` found it: the joints have not moved since.)
        origin, turn = self._eef
        centre = pb.multiplyTransforms(origin, turn, *self._carry_at)[0]
        rx, ry = centre[0] - origin[0], centre[1] - origin[1]
        weight = self._carry_load[0] * physics.GRAVITY[2]        # along z (negative)
        self._torque = (ry * weight, -rx * weight, 0.0)          # r × (0, 0, weight)

    @property
    def load_torque(self) -> tuple | None:
        """While carried: the torque load_wrist applies (world frame), as plan_load last set it; else None."""
        return self._torque if self.carried else None

    def load_wrist(self) -> None:
        """Before each physics step while carried (forces last one step in PyBullet)."""
        pb.applyExternalTorque(self.psm.body, EEF_LINK, self._torque, _WORLD_FRAME, self.client._client)

    def follow(self, velocity: bool = False) -> None:
        """While carried: the object at its pose in the hand (after a control period's physics steps); ``velocity``:
        moving with the wrist as well (when it rejoins the dynamics)."""
        # (computeForwardKinematics=1: PyBullet's stored frame of a link without a collision shape is what the last
        # forward-kinematics pass left, not what the last physics step did.)
        cid = self.client._client
        eef = pb.getLinkState(self.psm.body, EEF_LINK, int(velocity), 1, cid)
        self._eef = (eef[4], eef[5])
        pos = self._put(eef[4], eef[5])
        if velocity:
            v, w = eef[6], eef[7]
            rx, ry, rz = pos[0] - eef[4][0], pos[1] - eef[4][1], pos[2] - eef[4][2]
            pb.resetBaseVelocity(self.object_id, (v[0] + w[1] * rz - w[2] * ry, v[1] + w[2] * rx - w[0] * rz,
                                                  v[2] + w[0] * ry - w[1] * rx), w, cid)

    def follow_seen(self) -> None:
        """While carried, after each physics step for a probe that looks: the object where the hand has it now, the
        wrist's frame computed from the joint positions (Psm.wrist_frame), where the step left the blades' colliders.
        A forward-kinematics pass between two physics steps moves the solver's next result by ~1e-7 rad, growing to
        millimetres: a probe must leave the episode as it is without it. (A blade's stored frame, read without that
        pass, is the one the step began with: the object put by it lagged the blades by a step's motion, a blade up to
        1.48 mm inside a gauze carried under bang-bang input.)"""
        self._put(*self.psm.wrist_frame())

    def _put(self, origin, turn) -> None:
        pos, quat = pb.multiplyTransforms(origin, turn, *self._carry_at)
        pb.resetBasePositionAndOrientation(self.object_id, pos, quat, self.client._client)
        return pos

    def _end_carry(self) -> None:
        """The object back in the dynamics, where the hand has it and moving with it; the wrist link as built."""
        c = self.client
        self._set_collisions(HAND_LINKS, True)
        mass, inertia, link_mass, link_inertia = self._carry_load
        c.changeDynamics(self.object_id, -1, mass=mass, localInertiaDiagonal=list(inertia))
        self.follow(velocity=True)
        c.changeDynamics(self.psm.body, EEF_LINK, mass=link_mass, localInertiaDiagonal=list(link_inertia))
        self.carried = False
        self._carry_at = self._carry_load = None

    def restore(self) -> None:
        """End a carry: the weld back, with the frame and force it was made with."""
        if not self.carried:
            return
        self._end_carry()
        self.constraint = self._fix(self._frame, physics.GRASP_MAX_FORCE)

    def _held_by_peer(self) -> bool:
        return any(p.holds(self.object_id, self.object_link) for p in self.peers)

    def _grip(self) -> None:
        """The blades have just closed on the object: hold it by a constraint, or by the blades alone while a peer's
        constraint already drives it (see 5. Hand-over)."""
        self.hold_serial += 1
        if self._held_by_peer():
            self.passive = True
            self._held_at = self._relative_position()
            self.psm.hold_blades()
        else:
            self._attach(physics.GRASP_FRICTION_FORCE)

    def _take(self) -> None:
        """A passive hold becomes this hand's constraint, at the pose the object now has between its blades."""
        self.passive = False
        self.hold_serial += 1
        self._attach(physics.GRASP_MAX_FORCE if self.lift_condition() else physics.GRASP_FRICTION_FORCE)

    def attach(self) -> None:
        """Hold the object at its current pose relative to the wrist (a task that starts with it in hand)."""
        if self.constraint is None:
            self.hold_serial += 1
            self._attach(physics.GRASP_MAX_FORCE)

    def _relative_position(self) -> np.ndarray:
        return np.asarray(self._relative_pose()[0])

    def _relative_pose(self):
        """The held object's (position, quaternion) in the wrist-yaw link's frame."""
        return self._wrist_and_relative_pose()[1]

    def _wrist_and_relative_pose(self):
        """(the wrist-yaw link's world frame, the held object's pose in it), each a (position, quaternion)."""
        # (Asked for every step while holding: PyBullet called positionally, its keyword parsing costing more than
        # the calls; getLinkState's arguments are computeLinkVelocity=0, computeForwardKinematics=1.)
        cid = self.client._client
        eef = pb.getLinkState(self.psm.body, EEF_LINK, 0, 1, cid)
        if self.object_link < 0:
            obj_pos, obj_quat = pb.getBasePositionAndOrientation(self.object_id, cid)
        else:
            obj_pos, obj_quat = pb.getLinkState(self.object_id, self.object_link, 0, 1, cid)[:2]
        inv_pos, inv_quat = pb.invertTransform(eef[4], eef[5])
        return (eef[4], eef[5]), pb.multiplyTransforms(inv_pos, inv_quat, obj_pos, obj_quat)

    def _fix(self, frame, max_force: float) -> int:
        """A constraint holding the object at ``frame`` (position, quaternion) in the wrist-yaw link's frame."""
        c = self.client
        rel_pos, rel_quat = frame
        constraint = c.createConstraint(self.psm.body, EEF_LINK, self.object_id, self.object_link, c.JOINT_FIXED,
                                        [0, 0, 0], rel_pos, [0, 0, 0], parentFrameOrientation=rel_quat)
        c.changeConstraint(constraint, maxForce=max_force)
        return constraint

    def _attach(self, max_force: float) -> None:
        # Object pose in the wrist frame, so the constraint keeps the grasp exactly as found.
        rel_pos, rel_quat = self._relative_pose()
        self.constraint = self._fix((rel_pos, rel_quat), max_force)
        self.welded = max_force >= physics.GRASP_MAX_FORCE
        self._frame = (rel_pos, rel_quat)
        self._held_at = np.asarray(rel_pos)
        self.psm.hold_blades()
        self._set_collisions(JAW_JOINTS, False)

    def _set_collisions(self, links, enabled: bool) -> None:
        """Whether the tool's ``links`` collide with the object: not the blades of the hand whose constraint holds
        it (their contacts would only fight the weld), nor, while it is carried, the hand's shaft and wrist (between
        the steps of a period the object stays where ``follow`` last put it, behind the hand)."""
        for link in links:
            self.client.setCollisionFilterPair(self.psm.body, self.object_id, link, self.object_link, int(enabled))

    def release(self) -> None:
        if self.passive:
            self.passive = False
            self._held_at = None
            self.psm.stop_jaw_at(None)
        if self.constraint is not None:
            if self.carried:   # (its constraint is out of the solver already: nothing to remove)
                self._end_carry()
            else:
                self.client.removeConstraint(self.constraint)
            self.constraint = None
            self.welded = False
            self._held_at = None
            self.psm.stop_jaw_at(None)
            self._set_collisions(JAW_JOINTS, True)
            # A peer squeezing the same object takes it now, before the next physics step (nothing holds it else).
            for peer in self.peers:
                if peer.passive and peer.object_id == self.object_id and peer.object_link == self.object_link:
                    peer._take()
                    break

"""Grasping as on the instrument: the object must lie between the blades, and a weld that can break.

1. **Squeeze.** While the jaw closes, the blades collide with the object and stop on it, so the jaw angle
   reads the object's width.
2. **Grip.** Once both blades touch the object *on their inner faces* (contact normal across the closing gap,
   contact point along the blade, not past its end) with the jaw still open by more than the thinnest object
   leaves it, the object is fixed to the wrist at the pose it has in
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
   dropped: the weld goes, the jaw closes, ``drops`` counts it. Opening the jaw releases.
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

PyBullet keys pair filters by body ids, which removed bodies hand on: envs release every grasp before they
respawn bodies.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from surrol_data.envs import physics
from surrol_data.envs.numeric import vector_norm
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import EEF_LINK, JAW_JOINTS
from surrol_data.envs.units import SCALING

_TOUCH = physics.GRASP_CONTACT_DISTANCE_M * SCALING
_BLADE_LENGTH = physics.BLADE_LENGTH_M * SCALING
_ACROSS = np.cos(np.deg2rad(45.0))   # contact normal within 45° of the inner-face normal
_ORIGIN, _NO_TURN = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
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

    @property
    def attached(self) -> bool:
        """Holding the object: by a constraint, or (``passive``) by the blades while a peer's constraint holds it."""
        return self.constraint is not None or self.passive

    def holds(self, object_id: int, object_link: int) -> bool:
        """Whether this grasp's constraint drives that object (what a peer closing on it must not double)."""
        return self.constraint is not None and self.object_id == object_id and self.object_link == object_link

    def between_blades(self) -> bool:
        """Both blades touch the object on their inner faces, within the blade length, and the jaw is open
        (``physics.GRASP_MIN_OPENING_RAD``)."""
        if self.object_id < 0 or self.psm.jaw_angle() < physics.GRASP_MIN_OPENING_RAD:
            return False
        return all(self._inner_face_touch(j, towards) for j, towards in zip(JAW_JOINTS, _TOWARDS_OTHER))

    def _inner_face_touch(self, link: int, towards_other: float) -> bool:
        # (Run after every physics step while a jaw closes: PyBullet called positionally where it can.)
        cid = self.client._client
        points = pb.getClosestPoints(self.psm.body, self.object_id, _TOUCH, link, physicsClientId=cid)
        if not points:
            return False
        state = pb.getLinkState(self.psm.body, link, 0, 1, cid)
        inv_pos, inv_quat = pb.invertTransform(state[4], state[5])
        for p in points:
            along = pb.multiplyTransforms(inv_pos, inv_quat, p[6], _NO_TURN)[0][1]
            normal_x = pb.multiplyTransforms(_ORIGIN, inv_quat, p[7], _NO_TURN)[0][0]
            # p[7] points from the object to the blade: for an inner-face touch, away from the other blade.
            if -towards_other * normal_x > _ACROSS and -_TOUCH <= along <= _BLADE_LENGTH:
                return True
        return False

    def held_offset_m(self) -> float:
        """How far (real metres) the held object's frame sits from the wrist's origin, at most: where it was
        gripped plus the slip allowed before it is dropped (0 when nothing is held)."""
        if self._held_at is None:
            return 0.0
        return float(vector_norm(self._held_at)) / SCALING + self.max_slip_m

    def slip_m(self) -> float:
        """How far (real metres) the held object has moved in the hand since the weld formed."""
        if self._held_at is None:
            return 0.0
        return float(vector_norm(self._relative_position() - self._held_at)) / SCALING

    def grip_if_between(self) -> bool:
        """Called after every physics substep while the jaw closes: grip the moment both blades touch the
        object's sides. Checked per substep because a closing jaw crosses a 1.2 mm wire within one control
        step, and the blades must stop where they meet it (PyBullet's contacts alone let the arm's motors push
        a blade into the wire by a millimetre or more). Returns whether the object is now held."""
        if not self.attached and self.between_blades():
            self._grip()
        return self.attached

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

    def _held_by_peer(self) -> bool:
        return any(p.holds(self.object_id, self.object_link) for p in self.peers)

    def _grip(self) -> None:
        """The blades have just closed on the object: hold it by a constraint, or by the blades alone while a peer's
        constraint already drives it (see 5. Hand-over)."""
        if self._held_by_peer():
            self.passive = True
            self._held_at = self._relative_position()
            self.psm.hold_blades()
        else:
            self._attach(physics.GRASP_FRICTION_FORCE)

    def _take(self) -> None:
        """A passive hold becomes this hand's constraint, at the pose the object now has between its blades."""
        self.passive = False
        self._attach(physics.GRASP_MAX_FORCE if self.lift_condition() else physics.GRASP_FRICTION_FORCE)

    def attach(self) -> None:
        """Hold the object at its current pose relative to the wrist (a task that starts with it in hand)."""
        if self.constraint is None:
            self._attach(physics.GRASP_MAX_FORCE)

    def _relative_position(self) -> np.ndarray:
        return np.asarray(self._relative_pose()[0])

    def _relative_pose(self):
        # (Asked for every step while holding: PyBullet called positionally, its keyword parsing costing more than
        # the calls; getLinkState's arguments are computeLinkVelocity=0, computeForwardKinematics=1.)
        cid = self.client._client
        eef = pb.getLinkState(self.psm.body, EEF_LINK, 0, 1, cid)
        if self.object_link < 0:
            obj_pos, obj_quat = pb.getBasePositionAndOrientation(self.object_id, cid)
        else:
            obj_pos, obj_quat = pb.getLinkState(self.object_id, self.object_link, 0, 1, cid)[:2]
        inv_pos, inv_quat = pb.invertTransform(eef[4], eef[5])
        return pb.multiplyTransforms(inv_pos, inv_quat, obj_pos, obj_quat)

    def _attach(self, max_force: float) -> None:
        c = self.client
        # Object pose in the wrist frame, so the constraint keeps the grasp exactly as found.
        rel_pos, rel_quat = self._relative_pose()
        self.constraint = c.createConstraint(self.psm.body, EEF_LINK, self.object_id, self.object_link, c.JOINT_FIXED,
                                             [0, 0, 0], rel_pos, [0, 0, 0],
                                             parentFrameOrientation=rel_quat)
        c.changeConstraint(self.constraint, maxForce=max_force)
        self.welded = max_force >= physics.GRASP_MAX_FORCE
        self._held_at = np.asarray(rel_pos)
        self.psm.hold_blades()
        self._set_jaw_collisions(False)

    def _set_jaw_collisions(self, enabled: bool) -> None:
        for j in JAW_JOINTS:
            self.client.setCollisionFilterPair(self.psm.body, self.object_id, j, self.object_link, int(enabled))

    def release(self) -> None:
        if self.passive:
            self.passive = False
            self._held_at = None
            self.psm.stop_jaw_at(None)
        if self.constraint is not None:
            self.client.removeConstraint(self.constraint)
            self.constraint = None
            self.welded = False
            self._held_at = None
            self.psm.stop_jaw_at(None)
            self._set_jaw_collisions(True)
            # A peer squeezing the same object takes it now, before the next physics step (nothing holds it else).
            for peer in self.peers:
                if peer.passive and peer.object_id == self.object_id and peer.object_link == self.object_link:
                    peer._take()
                    break

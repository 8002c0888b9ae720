"""Grasping as on the instrument: the object must lie between the blades, and a weld that can break.

1. **Squeeze.** While the jaw closes, the blades collide with the object and stop on it, so the jaw angle
   reads the object's width.
2. **Grip.** Once both blades touch the object *on their inner faces* (contact normal across the closing gap,
   contact point along the blade, not past its end) with the jaw still open by more than the thinnest object
   leaves it, the object is fixed to the wrist at the pose it has in
   the hand by a constraint as strong as the squeeze's friction (``physics.GRASP_FRICTION_FORCE``). A closed
   jaw poked onto an object or swiped into it touches it with a blade's end or outer face and never grips.
3. **Weld.** Once the task's lift condition holds (the reference's ``_meet_contact_constraint_requirement``:
   e.g. the needle lifted 5 mm), the constraint gets the weld's full force (``physics.GRASP_MAX_FORCE``).
   The reference lifts by the friction of its squeezing jaws until then; PyBullet's contacts at our step
   size are too soft to squeeze without the blades closing through the object, so the grip stands in for
   that friction. While gripped or welded, the jaw is held at the angle it stopped at (it cannot close
   through the object), and the blades stop colliding with the held object:
   their contacts would only fight the weld (a block held by two hands gets twisted out of the second hand
   once the first lets go) and would make carrying cost 2–3× the physics of a free move.
4. **Drop.** The constraint's force is bounded (``physics.GRASP_MAX_FORCE``); pulled harder (the object caught on
   a peg, pushed into the board), the object slips in the hand, and past ``physics.GRASP_MAX_SLIP_M`` it is
   dropped: the weld goes, the jaw closes, ``drops`` counts it. Opening the jaw releases.

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
        self.drops = 0                   # welds lost to force or slip while the jaw stayed closed
        self._held_at: np.ndarray | None = None

    @property
    def attached(self) -> bool:
        return self.constraint is not None

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
        if self.constraint is None and self.between_blades():
            self._attach(physics.GRASP_FRICTION_FORCE)
        return self.constraint is not None

    def update(self, closing: bool) -> None:
        if not closing:
            self.release()
        elif self.constraint is None:
            if self.between_blades():
                self._attach(physics.GRASP_FRICTION_FORCE)
        elif self.slip_m() > self.max_slip_m:
            self.drops += 1
            self.release()
        elif not self.welded and self.lift_condition():
            self.client.changeConstraint(self.constraint, maxForce=physics.GRASP_MAX_FORCE)
            self.welded = True

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
        self.psm.stop_jaw_at(self.psm.jaw_angle())
        self._set_jaw_collisions(False)

    def _set_jaw_collisions(self, enabled: bool) -> None:
        for j in JAW_JOINTS:
            self.client.setCollisionFilterPair(self.psm.body, self.object_id, j, self.object_link, int(enabled))

    def release(self) -> None:
        if self.constraint is not None:
            self.client.removeConstraint(self.constraint)
            self.constraint = None
            self.welded = False
            self._held_at = None
            self.psm.stop_jaw_at(None)
            self._set_jaw_collisions(True)

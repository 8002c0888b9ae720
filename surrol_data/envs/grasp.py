"""Grasping by constraint: when both jaws touch the object while closing, fix the object to the wrist.

Friction grasps of millimetre objects need tiny time steps; a fixed constraint (as the dVRK simulators
do) is stable at our control rate. The constraint holds the object at the relative pose it had when
grasped, with a bounded force, and is removed when the jaw opens or neither jaw touches the object.
"""

from __future__ import annotations

from surrol_data.envs import physics
from surrol_data.envs.psm import EEF_LINK, JAW_JOINTS
from surrol_data.envs.units import SCALING

_TOUCH = physics.GRASP_CONTACT_DISTANCE_M * SCALING
_KEEP = 3 * _TOUCH  # hysteresis: once held, the object may sit a little away from the blades


class Grasp:
    """While the constraint holds the object, the jaws do not collide with it (as in the reference's approximate
    grasp); releasing restores the contacts. Why: the weld alone holds the object. Closing jaws sink about a
    millimetre into a held object and their contacts then push against the constraint — a block held by two
    hands gets twisted out of the second hand once the first lets go — and those contact rows make carrying
    cost 2–3× the physics of a free move. The touch test ignores collision filters. PyBullet keys pair
    filters by body ids, which removed bodies hand on: envs release every grasp before they respawn bodies."""

    def __init__(self, client, psm, object_id: int, collide_while_held: bool = False):
        self.client = client
        self.psm = psm
        self.object_id = object_id
        self.collide_while_held = collide_while_held
        self.constraint: int | None = None

    @property
    def attached(self) -> bool:
        return self.constraint is not None

    def jaws_touching(self, distance: float) -> bool:
        if self.object_id < 0:
            return False
        return all(self.client.getClosestPoints(self.psm.body, self.object_id, distance, linkIndexA=j)
                   for j in JAW_JOINTS)

    def update(self, closing: bool) -> None:
        if not closing:
            self.release()
        elif self.constraint is None:
            if self.jaws_touching(_TOUCH):
                self._attach()
        elif not self.jaws_touching(_KEEP):
            self.release()

    def attach(self) -> None:
        """Hold the object at its current pose relative to the wrist (a task that starts with it in hand)."""
        if self.constraint is None:
            self._attach()

    def _attach(self) -> None:
        c = self.client
        eef = c.getLinkState(self.psm.body, EEF_LINK, computeForwardKinematics=True)
        obj_pos, obj_quat = c.getBasePositionAndOrientation(self.object_id)
        # Object pose in the wrist frame, so the constraint keeps the grasp exactly as found.
        inv_pos, inv_quat = c.invertTransform(eef[4], eef[5])
        rel_pos, rel_quat = c.multiplyTransforms(inv_pos, inv_quat, obj_pos, obj_quat)
        self.constraint = c.createConstraint(self.psm.body, EEF_LINK, self.object_id, -1, c.JOINT_FIXED,
                                             [0, 0, 0], rel_pos, [0, 0, 0],
                                             parentFrameOrientation=rel_quat)
        c.changeConstraint(self.constraint, maxForce=physics.GRASP_MAX_FORCE)
        if not self.collide_while_held:
            self._set_jaw_collisions(False)

    def _set_jaw_collisions(self, enabled: bool) -> None:
        for j in JAW_JOINTS:
            self.client.setCollisionFilterPair(self.psm.body, self.object_id, j, -1, int(enabled))

    def release(self) -> None:
        if self.constraint is not None:
            self.client.removeConstraint(self.constraint)
            self.constraint = None
            if not self.collide_while_held:
                self._set_jaw_collisions(True)

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
    def __init__(self, client, psm, object_id: int):
        self.client = client
        self.psm = psm
        self.object_id = object_id
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

    def release(self) -> None:
        if self.constraint is not None:
            self.client.removeConstraint(self.constraint)
            self.constraint = None

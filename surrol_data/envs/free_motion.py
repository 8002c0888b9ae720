"""A tool that touches nothing, moved by its motors' own rule instead of by PyBullet's step.

Every joint of the PSM has a position motor (psm.py), and PyBullet's motor with velocity gain 1 asks for one thing
of its joint in a physics step of ``dt``: the velocity ``position gain × (target − position) / dt``, clamped at the
motor's max velocity (btMultiBodyJointMotor: the current velocity it adds and the velocity term it subtracts cancel).
While no contact acts on the arm and no motor needs more than its force limit for that, those eight velocities
are the whole solution of the step's constraints, whatever the masses, gravity or loads (they only set the forces),
and the positions advance by velocity × dt (btMultiBody::stepPositionsMultiDof). So such a period can be advanced in
closed form: no stepSimulation, nor its per-step commands (gravity compensation, the carried load, the target
ramp), which were more than half of a step carrying GauzeRetrieve's gauze at its goal.

When it holds (SubstepPlanner.free_arm: a single arm, whose object is carried kinematically and whose colliding
links cannot come within ``adaptive_steps.CARRY_CLEARANCE_M`` of anything over the period; no other body moves)
and the motors' forces stay within ``FORCE_MARGIN`` of their limits (:meth:`FreeMotion.plan`), the result is the
exact solution of the constraints PyBullet's solver iterates towards: measured on GauzeRetrieve's carried periods
(oracle, random and bang-bang input), PyBullet's own joint positions come within 2.5e-5 rad of it per physics
step (its 50 solver iterations leave that much of the coupled wrist rows unsolved), and the forces predicted here
within 7 % of a motor's limit of those PyBullet reports (tests/test_free_motion.py).
"""

from __future__ import annotations

import functools

import numpy as np

from surrol_data.envs import physics
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import EEF_LINK, JAW_JOINTS, MOTOR_FORCE_LIMITS, MOTOR_SPEED_CAPS

# The rule above holds for a velocity gain of exactly 1 (with any other the joint's own velocity stays in it, and
# that depends on the dynamics).
assert physics.PSM_VELOCITY_GAIN == 1.0, "free motion's closed form assumes PyBullet's motor velocity gain 1"

# The largest share of a motor's force limit the closed form may predict: the prediction takes the mass matrix and
# the static torques where the period starts and leaves out the velocity-dependent terms, which put it within 7 %
# of a limit of what PyBullet reports (GauzeRetrieve carried periods, bang-bang input); a motor predicted past this
# share has its period stepped by PyBullet, which limits the force.
FORCE_MARGIN = 0.8
_LIFTED_JOINTS = (0, 1, 2)   # the joints that carry link 2, which Psm.compensate_gravity pushes up
_MOVING = tuple(range(8))
_ZEROS = [0.0] * 8
_ORIGIN = (0.0, 0.0, 0.0)
_NO_TURN = (0.0, 0.0, 0.0, 1.0)
_FORCE_BOUNDS = FORCE_MARGIN * np.array(MOTOR_FORCE_LIMITS)
_SPEED_CAPS = np.array(MOTOR_SPEED_CAPS)


@functools.cache
def _period_basis(steps: int, dt: float) -> np.ndarray:
    """The joints' positions, velocities and accelerations after each of a period's ``steps`` physics steps (rows:
    steps × positions, then velocities, then accelerations) as combinations of (q0, targets, move, v0): where the
    joints start, the motors' targets where the ramp starts, the ramp's move (Psm.motor_ramp) and the joints' velocities
    at the start. Unclamped, each step takes the position gain's share of what is left to its target."""
    g = physics.PSM_POSITION_GAIN
    q, v_prev = np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])
    rows_q, rows_v, rows_a = [], [], []
    for i in range(1, steps + 1):
        target = np.array([0.0, 1.0, min(i / physics.RAMP_STEPS, 1.0), 0.0])
        v = g * (target - q) / dt
        rows_a.append((v - v_prev) / dt)
        q = q + dt * v
        rows_q.append(q)
        rows_v.append(v)
        v_prev = v
    return np.array(rows_q + rows_v + rows_a)


class FreeMotion:
    """The joint states (PyBullet's units) after each physics step of a control period moved in closed form."""

    def __init__(self, psm, positions: np.ndarray, velocities: np.ndarray, forces: np.ndarray):
        self.psm = psm
        self.positions = positions     # per physics step (rows): joints 0–7 after it
        self.velocities = velocities
        self.forces = forces           # the motors' forces in it (as predicted; within FORCE_MARGIN of the limits)

    @classmethod
    def plan(cls, psm, joint_states, steps: int, dt: float, load_torque=None) -> FreeMotion | None:
        """The period's ``steps`` physics steps of ``dt`` for ``psm``, whose joints 0–7 start in ``joint_states``
        (PyBullet's, Psm.moving_joint_states), or None where the rule does not hold (a motor at its max velocity, a
        blade at its stop, a motor needing more than ``FORCE_MARGIN`` of its force limit): then PyBullet must step
        it. ``load_torque``: the torque a carried object's weight puts on the wrist-yaw link (Grasp.plan_load),
        world frame. Reads PyBullet, changes nothing."""
        q0 = [s[0] for s in joint_states]
        targets, move = psm.motor_ramp()
        motion = _period_basis(steps, dt) @ np.array([q0, targets, move, [s[1] for s in joint_states]])
        q, v, a = motion[:steps], motion[steps:2 * steps], motion[2 * steps:]
        # A motor clamped at its max velocity breaks the linear rule (a tool moving at its speed limit is not
        # carrying quietly), and a blade at its stop has the limit's constraint act: such periods go to PyBullet.
        # (A jaw, never ramped, moves monotonically from where it is to its target: both within its limits will do.)
        lower, upper = psm.jaw_limits
        for j, lo, hi in zip(JAW_JOINTS, lower, upper):
            if not (lo <= q0[j] <= hi and lo <= targets[j] <= hi):
                return None
        if (np.abs(v).max(axis=0) > _SPEED_CAPS).any():
            return None
        forces = a @ cls._mass_matrix(psm, q0).T + cls._static_forces(psm, q0, load_torque)
        if (np.abs(forces).max(axis=0) > _FORCE_BOUNDS).any():
            return None
        return cls(psm, q, v, forces)

    @staticmethod
    def _mass_matrix(psm, q0: list) -> np.ndarray:
        return np.array(pb.calculateMassMatrix(psm.body, q0, physicsClientId=psm.client._client))

    @staticmethod
    def _static_forces(psm, q0: list, load_torque) -> list:
        """The motors' forces that hold the arm still where it is: gravity on every link (a carried object's mass
        is the wrist link's), less the gravity compensation's lift and the carried object's load torque."""
        cid = psm.client._client
        forces = pb.calculateInverseDynamics(psm.body, q0, _ZEROS, _ZEROS, physicsClientId=cid)
        # The lift acts at the planned centre of the carried links (a point of link 2, as of every link after it:
        # the Jacobian of the wrist-yaw link at that point has link 2's columns for joints 0–2, the lift's only
        # joints, and the wrist-yaw link's turn for every joint, the load torque's). The link's frame as PyBullet
        # has it stored: read without a forward-kinematics pass, which would move the solver's next result if
        # PyBullet steps this period after all (it may be a physics step old; the tests bound the whole prediction).
        frame = pb.getLinkState(psm.body, EEF_LINK, physicsClientId=cid)
        inv_pos, inv_rot = pb.invertTransform(frame[4], frame[5])
        local = pb.multiplyTransforms(inv_pos, inv_rot, psm.carried_centre, _NO_TURN)[0]
        lin, ang = pb.calculateJacobian(psm.body, EEF_LINK, local, q0, _ZEROS, _ZEROS, physicsClientId=cid)
        fx, fy, fz = psm.carried_lift
        forces = list(forces)
        for j in _LIFTED_JOINTS:
            forces[j] -= lin[0][j] * fx + lin[1][j] * fy + lin[2][j] * fz
        if load_torque is not None:
            tx, ty, tz = load_torque
            forces = [f - (x * tx + y * ty + z * tz) for f, x, y, z in zip(forces, *ang)]
        return forces

    def set_step(self, i: int) -> None:
        """Put the joints where physics step ``i`` (0-based) leaves them."""
        q, v = self.positions[i].tolist(), self.velocities[i].tolist()
        pb.resetJointStatesMultiDof(self.psm.body, _MOVING, [[x] for x in q], [[w] for w in v],
                                    physicsClientId=self.psm.client._client)

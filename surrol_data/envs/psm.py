"""The dVRK patient-side manipulator (PSM) as a PyBullet multibody built from primitives.

Link frames are the modified-DH frames of :mod:`surrol_data.envs.kinematics`, so PyBullet's joint
positions *are* the DH joint values (insertion scaled). The base of the multibody is the RCM frame:
the remote centre of motion is realised by the kinematic chain itself (yaw/pitch about the RCM point,
insertion through it), as on the real robot.

Link indices: 0 outer yaw, 1 outer pitch, 2 insertion, 3 tool roll, 4 wrist pitch, 5 wrist yaw (EEF),
6/7 jaws, 8 tool tip (fixed). The shaft (on the tool-roll link), the wrist and the jaws collide.
"""

from __future__ import annotations

from operator import mul as _mul

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import instrument_geometry
from surrol_data.envs import kinematics as kin
from surrol_data.envs import physics
from surrol_data.envs.shapes import convex_box
from surrol_data.envs.units import SCALING

ARM_JOINTS = (0, 1, 2, 3, 4, 5)
JAW_JOINTS = (6, 7)
HAND_LINKS = (3, 4)   # the tool's colliding links besides the blades: the shaft (on the roll link), the wrist
# The motors' limits, joints 0–7 (PyBullet's units: insertion scaled): max velocity and max force.
MOTOR_SPEED_CAPS = tuple(physics.scaled_velocity_limits().tolist()) + (physics.JAW_MAX_VELOCITY,) * len(JAW_JOINTS)
MOTOR_FORCE_LIMITS = tuple(physics.PSM_MAX_FORCE) + (physics.JAW_MAX_FORCE,) * len(JAW_JOINTS)
TIP_LINK = 8
EEF_LINK = 5
# Joint value of each jaw = sign × jaw angle / 2: the +x blade opens towards +x (a negative rotation about z).
_JAW_SIGNS = (-1.0, +1.0)

_SHAFT_RADIUS_M = 0.004
_SHAFT_COLLISION_LENGTH_M = 0.06

_MOVING_JOINTS = ARM_JOINTS + JAW_JOINTS
_HELD_REVOLUTE = (0, 1, 3, 4, 5)         # the revolute joints that turn the wrist-yaw link (what grasps hold on to)
_POSITION_CONTROL = pb.POSITION_CONTROL
_WORLD_FRAME = pb.WORLD_FRAME
_ROLL_LOWER, _ROLL_UPPER = float(kin.PSM_LOWER[3]), float(kin.PSM_UPPER[3])
_CARRIED_LINKS = (2, 3, 4, 5, 6, 7, 8)   # the links the insertion joint carries (gravity compensation)
# Joints whose targets ramp step by step (they carry the tip); the wrist's get their targets at once (their
# blade-end speeds are small, and a 30° turn needs the whole period at the wrist's speed limit).
_RAMPED_JOINTS = (0, 1, 2)
_WRIST_JOINTS = (3, 4, 5)
_RAMP_ZEROS = [0.0] * len(_RAMPED_JOINTS)
_RAMP_FORCES = [physics.PSM_MAX_FORCE[k] for k in _RAMPED_JOINTS]
_RAMP_POSITION_GAINS = [physics.PSM_POSITION_GAIN] * len(_RAMPED_JOINTS)
_RAMP_VELOCITY_GAINS = [physics.PSM_VELOCITY_GAIN] * len(_RAMPED_JOINTS)
# Levers (real metres per scaled unit of joint motion) from joints 2–7 to the blade ends: insertion (scaled),
# tool roll (blades within ~2 mm of the shaft axis), wrist pitch (wrist + blade), wrist yaw and the jaws (blade).
_BLADE_LEVERS = (1.0 / SCALING, 0.002, kin.WRIST_LENGTH + kin.TIP_LENGTH, kin.TIP_LENGTH, kin.TIP_LENGTH,
                 kin.TIP_LENGTH)

# Jaw blade: 1.4 mm thick (opening direction), 10.2 mm long, 1.8 mm wide; offset so closed blades meet.
_JAW_HALF = np.array([0.0007, 0.0051, 0.0009])
# Each jaw joint's limits: a blade cannot swing past the closed position (see _create_body).
_JAW_LOWER = tuple(float(min(0.0, sign * (kin.JAW_LIMITS[1] / 2))) for sign in _JAW_SIGNS)
_JAW_UPPER = tuple(float(max(0.0, sign * (kin.JAW_LIMITS[1] / 2))) for sign in _JAW_SIGNS)


def _joint_speed_bound(state, target: float, cap: float, ramp_s: float) -> float:
    """How fast a joint may move over the next control period: the faster of its current speed and the speed that
    covers the rest of its move within the target ramp, capped by its limit (``state``: PyBullet's joint state)."""
    return max(abs(state[1]), min(cap, abs(target - state[0]) / ramp_s))


def matrix_to_quat(m: np.ndarray):
    # PyBullet has no matrix→quaternion helper; a trace-based conversion, robust near 180° rotations.
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    return [x, y, z, w]


def quat_to_matrix(client, q) -> np.ndarray:
    return np.asarray(client.getMatrixFromQuaternion(q)).reshape(3, 3)


class Psm:
    """One PSM. Positions in and out are real metres in the world frame; the RCM pose is fixed at build."""

    def __init__(self, client, rcm_position_m, rcm_yaw_rad: float = 0.0, visual: bool = True):
        self.client = client
        self.visual = visual
        self.world_T_rcm = np.eye(4)
        self.world_T_rcm[:3, :3] = kin.rot_z3(rcm_yaw_rad)
        self.world_T_rcm[:3, 3] = rcm_position_m
        self.rcm_T_world = np.linalg.inv(self.world_T_rcm)
        self._cid = client._client     # PyBullet's client id, for the per-physics-step calls (no wrapper)
        self.body = self._build()
        self._vmax_list = list(MOTOR_SPEED_CAPS[:len(ARM_JOINTS)])
        self._goal_targets = (0.0,) * 8   # joints 0–7 where the motors are headed (insertion scaled)
        self._q_target = np.zeros(6)     # where the arm is going (the last accepted command)
        self._q_motor = [0.0] * 6        # what the motors are set to now
        # The ramp of the ramped joints: where it started and the whole move (floats; the motors' targets along
        # it are start + move × fraction, the arithmetic numpy did on arrays before, without its overhead).
        self._ramp_start = [0.0] * len(_RAMPED_JOINTS)
        self._ramp_move = [0.0] * len(_RAMPED_JOINTS)
        self._ramp_done = True
        self._jaw_target = 0.0
        self._jaw_stop: float | None = None
        self._jaw_skew = 0.0   # both blades' common turn while they hold an object (see hold_blades)
        self._jaw_limits = (_JAW_LOWER, _JAW_UPPER)
        self._carried_weights = tuple(-self._spec["linkMasses"][j] * physics.GRAVITY[2] for j in _CARRIED_LINKS)
        self._carried_lift = (0.0, 0.0, sum(self._carried_weights))
        self._carried_com = (0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ construction
    def _build(self) -> int:
        c = self.client
        S = SCALING
        positions, orientations, parents, joint_types, axes = [], [], [], [], []
        cols, viss, masses = [], [], []
        for i, row in enumerate(kin.PSM_DH):
            fixed = kin.dh_fixed_transform(row)
            positions.append((fixed[:3, 3] * S).tolist())
            orientations.append(matrix_to_quat(fixed[:3, :3]))
            parents.append(i)  # PyBullet parent indices are 1-based into links (0 = base)
            joint_types.append(pb.JOINT_PRISMATIC if row[4] else pb.JOINT_REVOLUTE)
            axes.append([0, 0, 1])
            masses.append(physics.PSM_LINK_MASS)
            cols.append(-1)
            viss.append(-1)
        # Visuals: the EndoWrist of instrument_geometry (shaft, clevis, wrist, blades), one shape array per link.
        if self.visual:
            viss[3] = instrument_geometry.instrument_visual_shape(c, "shaft", S)
            viss[4] = instrument_geometry.instrument_visual_shape(c, "wrist", S)
        # The shaft collides too (the reference's tool-roll link has a collision mesh): an 8 mm capsule whose lower
        # cap ends at the wrist, so a tool swept sideways stops on a tray wall or a peg instead of passing through.
        # Only its lowest 6 cm can reach anything on the table (the peg tops, the highest things there, are
        # < 3 cm above the lowest wrist position); a full-length capsule would overlap the table's bounding box
        # and cost a narrow-phase test every physics step.
        r = _SHAFT_RADIUS_M * S
        collide_len = _SHAFT_COLLISION_LENGTH_M * S
        cols[3] = c.createCollisionShape(pb.GEOM_CAPSULE, radius=r, height=collide_len - 2 * r,
                                         collisionFramePosition=[0, 0, -collide_len / 2])
        # Wrist pitch link: a short capsule from the pitch axis to the yaw axis (along its x axis).
        wrist_q = matrix_to_quat(np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float))
        cols[4] = c.createCollisionShape(pb.GEOM_CAPSULE, radius=0.0025 * S, height=kin.WRIST_LENGTH * S * 0.6,
                                         collisionFramePosition=[kin.WRIST_LENGTH * S / 2, 0, 0],
                                         collisionFrameOrientation=wrist_q)
        # Jaws: revolute about the wrist-yaw axis (z of frame 6), blades along +y, opening along ±x.
        for sign in (+1.0, -1.0):
            centre = np.array([sign * _JAW_HALF[0], _JAW_HALF[1], 0.0]) * S
            cols.append(convex_box(c, _JAW_HALF * S, centre))
            viss.append(instrument_geometry.instrument_visual_shape(c, "jaw_plus" if sign > 0 else "jaw_minus", S)
                        if self.visual else -1)
            positions.append([0, 0, 0])
            orientations.append([0, 0, 0, 1])
            parents.append(6)
            joint_types.append(pb.JOINT_REVOLUTE)
            axes.append([0, 0, 1])
            masses.append(physics.JAW_MASS)
        # Tool tip: fixed frame, no collision.
        positions.append((kin.TOOL_TIP_OFFSET[:3, 3] * S).tolist())
        orientations.append(matrix_to_quat(kin.TOOL_TIP_OFFSET[:3, :3]))
        parents.append(6)
        joint_types.append(pb.JOINT_FIXED)
        axes.append([0, 0, 1])
        masses.append(physics.PSM_LINK_MASS)
        cols.append(-1)
        viss.append(-1)

        n = len(masses)
        base_vis = c.createVisualShape(pb.GEOM_SPHERE, radius=0.004 * S, rgbaColor=(0.9, 0.6, 0.1, 1.0)) \
            if self.visual else -1
        self._spec = dict(
            baseMass=0.0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=base_vis,
            basePosition=(self.world_T_rcm[:3, 3] * S).tolist(),
            baseOrientation=matrix_to_quat(self.world_T_rcm[:3, :3]),
            linkMasses=masses, linkCollisionShapeIndices=cols, linkVisualShapeIndices=viss,
            linkPositions=positions, linkOrientations=orientations,
            linkInertialFramePositions=[[0, 0, 0]] * n, linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
            linkParentIndices=parents, linkJointTypes=joint_types, linkJointAxis=axes,
            useMaximalCoordinates=False)
        return self._create_body()

    def _create_body(self) -> int:
        c = self.client
        self._ramp_limits_sent = False   # a fresh body's motors have no speed limits yet
        body = c.createMultiBody(**self._spec)
        n = len(self._spec["linkMasses"])
        for j in range(n):
            c.changeDynamics(body, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0)
        for j in ARM_JOINTS:
            c.changeDynamics(body, j, localInertiaDiagonal=[physics.PSM_LINK_INERTIA] * 3)
        for j, sign in zip(JAW_JOINTS, _JAW_SIGNS):
            c.changeDynamics(body, j, lateralFriction=physics.JAW_FRICTION, spinningFriction=0.0,
                             localInertiaDiagonal=[physics.JAW_INERTIA] * 3)
            # A blade cannot swing past the closed position (into the other blade's place), however hard a
            # surface pushes it: the squeeze motor is weak (physics.JAW_MAX_FORCE), and without this stop a
            # closed jaw pushed over the pad under bang-bang input ended with its blades crossed by 11°.
            k = j - JAW_JOINTS[0]
            c.changeDynamics(body, j, jointLowerLimit=_JAW_LOWER[k], jointUpperLimit=_JAW_UPPER[k])
        return body

    def respawn(self) -> None:
        """Replace the body by a fresh one from the same shapes: no solver or motor state survives."""
        self.client.removeBody(self.body)
        self.body = self._create_body()
        self._jaw_stop = None
        self._jaw_skew = 0.0
        self._jaw_limits = (_JAW_LOWER, _JAW_UPPER)

    def plan_gravity_compensation(self) -> None:
        """Once per control period: where the weight of the links that move with the insertion (2–8) acts."""
        states = pb.getLinkStates(self.body, _CARRIED_LINKS, physicsClientId=self._cid)
        weights, total = self._carried_weights, self._carried_lift[2]   # (the lift is the weights' sum)
        # The weighted sums of the links' x, y and z, as sum() adds them (map and operator.mul: the same products
        # in the same order, without a generator per axis).
        xs, ys, zs = zip(*[state[0] for state in states])
        self._carried_com = (sum(map(_mul, weights, xs)) / total, sum(map(_mul, weights, ys)) / total,
                             sum(map(_mul, weights, zs)) / total)

    def compensate_gravity(self) -> None:
        """Before a physics step: hold up the arm's weight, as the dVRK's gravity compensation does.

        The weight of links 2–8 is applied back, upwards, at their common centre of mass (found once per control
        period; it moves ≤ 5 cm scaled within one, a torque error < 1 % of the motors' limits): that cancels
        gravity's torque on the outer yaw and pitch and its force on the insertion (links 0 and 1 sit on both axes
        and feel none). The wrist joints still carry their own few grams, < 10 % of their motors' limit. One
        PyBullet call per physics step: a force per link at its own centre cost ~40 % of a step."""
        # (objectUniqueId, linkIndex, forceObj, posObj, flags, physicsClientId: positional, as it runs every step)
        pb.applyExternalForce(self.body, 2, self._carried_lift, self._carried_com, _WORLD_FRAME, self._cid)

    # ------------------------------------------------------------------ state
    def reset_joints(self, q, jaw: float) -> None:
        c = self.client
        q = np.asarray(q, float)
        qs = q.copy()
        qs[2] *= SCALING
        for j, v in zip(ARM_JOINTS, qs):
            c.resetJointState(self.body, j, v, 0.0)
        for j, sign in zip(JAW_JOINTS, _JAW_SIGNS):
            c.resetJointState(self.body, j, sign * jaw / 2, 0.0)
        self._q_target = q.copy()
        self._set_goal_targets()
        self._ramp_done = True
        self._jaw_target = jaw
        self._apply_arm_targets(q)
        self._apply_jaw_target()

    def joint_positions(self) -> np.ndarray:
        states = pb.getJointStates(self.body, ARM_JOINTS, self._cid)
        q = np.array([s[0] for s in states])
        q[2] /= SCALING
        return q

    def joint_velocities(self) -> np.ndarray:
        states = self.client.getJointStates(self.body, ARM_JOINTS)
        v = np.array([s[1] for s in states])
        v[2] /= SCALING
        return v

    def moving_joint_states(self) -> tuple:
        """PyBullet's states (position, velocity, …) of joints 0–7 (insertion scaled)."""
        return pb.getJointStates(self.body, _MOVING_JOINTS, physicsClientId=self._cid)

    @property
    def goal_targets(self) -> tuple:
        """Where the motors of joints 0–7 are headed (the last accepted command; insertion scaled)."""
        return self._goal_targets

    def blade_speed_bound(self, dt: float, states: tuple | None = None) -> float:
        """A bound (real m/s) on how fast any point of the blades moves over the next control period of physics
        steps of ``dt``: per joint the faster of its current speed and the speed that covers the rest of its
        move within the target ramp (capped by the joint's limit), times that joint's lever to the blade ends.
        (Plain floats: numpy's per-call overhead on 8-element arrays would cost more than the arithmetic.)"""
        if states is None:
            states = self.moving_joint_states()
        targets = self._goal_targets
        caps = MOTOR_SPEED_CAPS
        ramp = physics.RAMP_STEPS * dt
        reach = states[2][0] / SCALING + kin.WRIST_LENGTH + kin.TIP_LENGTH   # RCM to blade ends, real metres
        levers = (reach, reach) + _BLADE_LEVERS
        bound = 0.0
        for state, target, cap, lever in zip(states, targets, caps, levers):
            bound += _joint_speed_bound(state, target, cap, ramp) * lever
        return bound

    def held_speed_bound(self, dt: float, offset_m: float, states: tuple, blade_bound: float) -> float:
        """A bound (real m/s) on how fast a point fixed to the wrist-yaw link (where a grasp holds its object),
        ``offset_m`` from that link's origin, moves over the next control period: the blades' bound
        (``blade_bound``, from :meth:`blade_speed_bound` with the same ``states``) plus the offset times the
        revolute arm joints' speeds (the held point turns with them; the jaws do not carry it)."""
        targets = self._goal_targets
        caps = MOTOR_SPEED_CAPS
        ramp = physics.RAMP_STEPS * dt
        turn = 0.0
        for j in _HELD_REVOLUTE:
            turn += _joint_speed_bound(states[j], targets[j], caps[j], ramp)
        return blade_bound + offset_m * turn

    def jaw_angle(self) -> float:
        a, b = pb.getJointStates(self.body, JAW_JOINTS, self._cid)
        return float(_JAW_SIGNS[0] * a[0] + _JAW_SIGNS[1] * b[0])

    def tip_pose(self) -> np.ndarray:
        """World pose of the tool tip (4×4, real metres), from the simulated joint positions."""
        return self.world_T_rcm.dot(kin.psm_fk(self.joint_positions()))   # (.dot: see kinematics)

    def wrist_frame(self) -> tuple:
        """The wrist-yaw (EEF) link's world frame (scaled position, quaternion) at the joint positions now, without a
        forward-kinematics pass (which moves the solver's next result). After a physics step the link colliders are
        at the new joint positions but PyBullet's stored link frames (``getLinkState`` without that pass) are still
        those the step began with: a carried gauze put in the hand by a blade's stored frame lagged the blades by a
        physics step's motion, up to 1.4 mm inside one under bang-bang input."""
        t = self.world_T_rcm.dot(kin.psm_link_frames(self.joint_positions())[EEF_LINK])
        return (t[:3, 3] * SCALING).tolist(), matrix_to_quat(t[:3, :3])

    def link_pose_world(self, link: int) -> tuple[np.ndarray, np.ndarray]:
        """(position in real metres, rotation matrix) of a link, as PyBullet simulates it."""
        st = self.client.getLinkState(self.body, link, computeForwardKinematics=True)
        return np.asarray(st[4]) / SCALING, quat_to_matrix(self.client, st[5])

    # ------------------------------------------------------------------ commands
    def ik(self, tip_pose_world: np.ndarray) -> kin.IKResult:
        return kin.psm_ik(self.rcm_T_world.dot(tip_pose_world))

    def command_tip(self, tip_pose_world: np.ndarray, ramp: bool = False) -> bool:
        """Set joint targets for a tip pose. Out-of-limit solutions are refused (the arm keeps its target).

        ``ramp``: the motors' targets move there in straight joint-space steps as :meth:`ramp_targets` is called
        (once per physics step), instead of jumping there at once; see ``physics.RAMP_STEPS``."""
        sol = self.ik(tip_pose_world)
        if not sol.within_limits:
            return False
        q = sol.q.copy()
        # Keep roll continuous: pick the 2π-equivalent closest to the current target within limits.
        roll, current = float(q[3]), float(self._q_target[3])
        for cand in (roll - 2 * np.pi, roll + 2 * np.pi):
            if _ROLL_LOWER <= cand <= _ROLL_UPPER and abs(cand - current) < abs(roll - current):
                roll = cand
        q[3] = roll
        self._q_target = q
        self._set_goal_targets()
        if ramp:
            target = q.tolist()
            self._ramp_start = [self._q_motor[k] for k in _RAMPED_JOINTS]
            self._ramp_move = [target[k] - self._q_motor[k] for k in _RAMPED_JOINTS]
            self._ramp_done = False
            self._apply_arm_targets(q, _WRIST_JOINTS)
        else:
            self._ramp_done = True
            self._apply_arm_targets(q)
        return True

    def _set_goal_targets(self) -> None:
        goal = self._q_target.tolist()
        goal[2] *= SCALING
        self._goal_targets = tuple(goal) + self._goal_targets[6:]

    @property
    def jaw_limits(self) -> tuple:
        """(lower, upper) joint limits of the two jaw joints, where PyBullet stops them (see _create_body). While the
        blades hold an object each is also stopped on its closing side where it met the object (hold_blades), at its
        motor's target: a blade moved towards that target stays within it, so the stop does not act on it."""
        return _JAW_LOWER, _JAW_UPPER

    def _set_jaw_limits(self, lower: tuple, upper: tuple) -> None:
        lower, upper = tuple(float(x) for x in lower), tuple(float(x) for x in upper)
        for k, j in enumerate(JAW_JOINTS):
            self.client.changeDynamics(self.body, j, jointLowerLimit=lower[k], jointUpperLimit=upper[k])
        self._jaw_limits = (lower, upper)

    @property
    def carried_centre(self) -> tuple:
        """Where compensate_gravity's lift acts (world, scaled): the centre of the links 2–8, as last planned."""
        return self._carried_com

    @property
    def carried_lift(self) -> tuple:
        """compensate_gravity's lift (world, scaled): the weight of links 2–8, upwards."""
        return self._carried_lift

    def motor_ramp(self) -> tuple[list, list]:
        """(targets, move): the motors' targets of joints 0–7 (PyBullet's units) where the period's ramp starts, and
        the ramp's whole move (zero for all but the ramped joints, all zero once it is done): before physics step
        ``i`` :meth:`ramp_targets` sets targets + move × min((i + 1) / RAMP_STEPS, 1) (at 1 the command itself)."""
        motor = self._q_motor
        ramped = motor[:3] if self._ramp_done else self._ramp_start
        targets = [ramped[0], ramped[1], ramped[2] * SCALING] + motor[3:6] + list(self._goal_targets[6:])
        if self._ramp_done:
            return targets, [0.0] * 8
        move = self._ramp_move
        return targets, [move[0], move[1], move[2] * SCALING] + [0.0] * 5

    def finish_ramp(self, steps: int) -> None:
        """The motors where a period of ``steps`` physics steps' ramp_targets calls leaves them."""
        if not self._ramp_done:
            self.ramp_targets(min(steps, physics.RAMP_STEPS) - 1)

    def ramp_targets(self, step: int) -> None:
        """Before physics step ``step`` (0-based) of a control period: advance the motor targets along the ramp."""
        if self._ramp_done:
            return
        f = (step + 1) / physics.RAMP_STEPS
        if f >= 1.0:
            self._ramp_done = True
            # (The wrist's motors got their targets with the command, at the same time step: only the ramped
            # joints change.)
            self._apply_ramped_targets(self._q_target.tolist()[:3])
        else:
            self._apply_ramped_targets([a + d * f for a, d in zip(self._ramp_start, self._ramp_move)])

    def _apply_ramped_targets(self, q: list) -> None:
        """Set the motors of the ramped joints (0–2) to ``q``: one PyBullet command for the three once their
        speed limits are set (the array form cannot send them, and the motors keep the last ones sent)."""
        if not self._ramp_limits_sent:
            self._apply_arm_targets(q, _RAMPED_JOINTS)
            return
        motor = self._q_motor
        motor[0], motor[1], motor[2] = float(q[0]), float(q[1]), float(q[2])
        pb.setJointMotorControlArray(self.body, _RAMPED_JOINTS, _POSITION_CONTROL,
                                     [motor[0], motor[1], motor[2] * SCALING], _RAMP_ZEROS, _RAMP_FORCES,
                                     _RAMP_POSITION_GAINS, _RAMP_VELOCITY_GAINS, self._cid)

    def command_jaw(self, angle: float) -> None:
        angle = float(min(max(angle, kin.JAW_LIMITS[0]), kin.JAW_LIMITS[1]))
        self._jaw_target = angle if self._jaw_stop is None else max(angle, self._jaw_stop)
        self._apply_jaw_target()

    def stop_jaw_at(self, angle: float | None) -> None:
        """Close no further than ``angle`` (rad) — a welded object between the blades — or, None, freely (and
        the blades symmetric about the wrist again)."""
        self._jaw_stop = angle
        if angle is None and self._jaw_limits != (_JAW_LOWER, _JAW_UPPER):
            self._set_jaw_limits(_JAW_LOWER, _JAW_UPPER)
        if angle is None and self._jaw_skew != 0.0:
            self._jaw_skew = 0.0
            self._apply_jaw_target()
        if angle is not None and self._jaw_target < angle:
            self._jaw_target = angle
            self._apply_jaw_target()

    def hold_blades(self) -> None:
        """Stop each blade where it is: an object between them (until ``stop_jaw_at(None)``).

        A jaw closing on an object off its centre line meets it with one blade first, and that blade is held back
        while the other closes: the two stop turned together (skewed) about the wrist. Stopping only the
        opening angle let the blades swing back to their symmetric targets after the grip, into the held object
        (which no longer collides with them) and off it: a block gripped at the blade ends under bang-bang
        input then lay 0.6 mm inside one blade and 0.5 mm clear of the other (benchmarks/physics_realism.py,
        BiPegTransfer seed 8, step 16)."""
        a, b = pb.getJointStates(self.body, JAW_JOINTS, self._cid)
        # Each blade stops where it is by its joint limit on the closing side (the jaw motor is too weak to: whipped
        # round by bang-bang wrist moves, a held block's blade closed 1.5 mm into it, the jaw from 21° to 11°,
        # BiPegTransfer seed 4), as the object between them would stop it if they still collided with it.
        self._set_jaw_limits((_JAW_LOWER[0], b[0]), (a[0], _JAW_UPPER[1]))
        self._jaw_skew = float((a[0] + b[0]) / 2)
        self._jaw_stop = float(_JAW_SIGNS[0] * a[0] + _JAW_SIGNS[1] * b[0])
        self._jaw_target = max(self._jaw_target, self._jaw_stop)
        self._apply_jaw_target()

    def _apply_arm_targets(self, q, joints=ARM_JOINTS) -> None:
        """Set the motors of ``joints`` (default all six) to ``q``'s values (``q`` indexed by joint, as ``joints``;
        a list of the ramped joints' values when ``joints`` are those)."""
        motor = self._q_motor
        for k in joints:
            motor[k] = float(q[k])
        if joints[:3] == _RAMPED_JOINTS:
            self._ramp_limits_sent = True
        for k in joints:
            # Positional arguments: PyBullet's keyword parsing costs more than the call itself.
            pb.setJointMotorControl2(self.body, ARM_JOINTS[k], _POSITION_CONTROL,
                                     motor[k] * SCALING if k == 2 else motor[k], 0.0, physics.PSM_MAX_FORCE[k],
                                     physics.PSM_POSITION_GAIN, physics.PSM_VELOCITY_GAIN, self._vmax_list[k],
                                     self._cid)

    def reapply_motors(self) -> None:
        """Re-issue the motor commands: PyBullet turns a motor's force limit into an impulse limit with the time
        step current when the command is given, so after a change of time step they must be given again."""
        self._apply_arm_targets(self._q_motor)
        self._apply_jaw_target()

    def _apply_jaw_target(self) -> None:
        skew = self._jaw_skew
        self._goal_targets = self._goal_targets[:6] + tuple(sign * self._jaw_target / 2 + skew for sign in _JAW_SIGNS)
        for j, sign in zip(JAW_JOINTS, _JAW_SIGNS):
            # (targetPosition, targetVelocity, force, positionGain, velocityGain, maxVelocity, client)
            pb.setJointMotorControl2(self.body, j, _POSITION_CONTROL, sign * self._jaw_target / 2 + skew, 0.0,
                                     physics.JAW_MAX_FORCE, physics.PSM_POSITION_GAIN, physics.PSM_VELOCITY_GAIN,
                                     physics.JAW_MAX_VELOCITY, self._cid)

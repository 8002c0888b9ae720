"""The pick-and-place training kit: coloured jacks and open trays of matching colour, built from primitives.

Real-world sizes (millimetres) and where they come from:

* **Jack**: the paper's task ("pick up the colored jacks and place them in the tray in the same color", the
  robotic-surgery curriculum's Pick and Place) names the object but gives no size, and the reference's v2 assets
  are unscaled meshes. Ours is a children's jack: six arms along three orthogonal axes, 16.4 mm across the arm
  ends (arms 6.8 mm from the centre plus a 1.2 mm end radius) with 2.4 mm thick arms. The size is our choice,
  set by the tool: an arm must fit between the PSM's jaws, whose blades open 40° and are 10.2 mm long (the
  reference's jaw geometry, 7 mm apart at their tips), and two jacks and two trays must fit the reference's
  10 cm × 10 cm tip workspace. Mass 5 g (a plastic part of this size weighs a few grams).
* **Tray**: an open square dish, 26 mm inside, 1.5 mm walls, 7 mm tall (our choice: a jack dropped within a
  few millimetres of its centre lands inside, and two trays fit side by side in the workspace with room for the
  jacks; the reference's v2 branch places its two "pots" 55 mm apart for the same purpose).

A jack at rest stands on the ends of three arms (its body diagonal vertical), so three arms point up at
35.3° above the horizontal: those are the ones a tool reaching down from above grasps.

Positions are real metres in the world frame; every builder takes the client explicitly.
"""

from __future__ import annotations

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import objects, physics
from surrol_data.envs.psm import matrix_to_quat
from surrol_data.envs.units import SCALING

_MM = 1e-3

JACK_ARM_LENGTH = 6.8 * _MM      # centre to the centre of an arm's rounded end
JACK_ARM_RADIUS = 1.2 * _MM
JACK_MASS = 0.005
# Sitting on three arm ends: the centre is this high above the surface.
JACK_REST_HEIGHT = JACK_ARM_LENGTH / np.sqrt(3.0) + JACK_ARM_RADIUS
UP_ARM_ELEVATION = np.arcsin(1.0 / np.sqrt(3.0))    # 35.26°

TRAY_INNER_HALF = 13.0 * _MM
TRAY_WALL = 1.5 * _MM
TRAY_WALL_HEIGHT = 7.0 * _MM
TRAY_FLOOR = 1.0 * _MM           # floor thickness: the floor's top is this far above the table

COLOURS = {"red": (0.85, 0.15, 0.12, 1.0), "green": (0.15, 0.65, 0.25, 1.0), "blue": (0.2, 0.4, 0.85, 1.0)}


def _rest_rotation() -> np.ndarray:
    """Rotation that stands the jack on the ends of its −x, −y, −z arms (body diagonal (1, 1, 1) up)."""
    up = np.ones(3) / np.sqrt(3.0)
    e1 = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    e2 = np.cross(up, e1)
    return np.stack([e1, e2, up])     # rows: maps body (1, 1, 1)/√3 to world z


REST_ROTATION = _rest_rotation()


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------------- jacks
def jack_spec(client, colour, visual: bool = True) -> dict:
    """``createMultiBody`` arguments of one jack: three capsules crossing at its centre."""
    r = JACK_ARM_RADIUS * SCALING
    length = 2 * JACK_ARM_LENGTH * SCALING
    # Capsules lie along their z axis: rotate them onto x, y and z.
    quats = [pb.getQuaternionFromEuler([0.0, np.pi / 2, 0.0]), pb.getQuaternionFromEuler([np.pi / 2, 0.0, 0.0]),
             [0.0, 0.0, 0.0, 1.0]]
    zeros = [[0.0, 0.0, 0.0]] * 3
    col = client.createCollisionShapeArray([pb.GEOM_CAPSULE] * 3, radii=[r] * 3, lengths=[length] * 3,
                                           collisionFramePositions=zeros, collisionFrameOrientations=quats)
    vis = client.createVisualShapeArray([pb.GEOM_CAPSULE] * 3, radii=[r] * 3, lengths=[length] * 3,
                                        visualFramePositions=zeros, visualFrameOrientations=quats,
                                        rgbaColors=[colour] * 3) if visual else -1
    return dict(baseMass=JACK_MASS, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis, basePosition=[0, 0, 0])


def _jack_inertia() -> list[float]:
    # Three thin rods of a third of the mass each, 2L long: isotropic, 2mL²/9 about every axis.
    length = JACK_ARM_LENGTH * SCALING
    i = 2.0 * JACK_MASS * length ** 2 / 9.0
    return [i, i, i]


def spawn_jack(client, spec: dict) -> int:
    """A fresh jack from ``spec``, allowed to sleep once it rests."""
    return objects.spawn_rigid_object(client, spec, JACK_MASS, _jack_inertia())


def place_jack(client, body: int, xy, floor_z: float, yaw: float) -> None:
    """Stand the jack on three arm ends on a surface at ``floor_z``, turned ``yaw`` about the vertical, at rest."""
    rot = _rot_z(yaw) @ REST_ROTATION
    position = np.array([xy[0], xy[1], floor_z + JACK_REST_HEIGHT]) * SCALING
    client.resetBasePositionAndOrientation(body, position.tolist(), matrix_to_quat(rot))
    client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


def jack_pose(client, body: int) -> tuple[np.ndarray, np.ndarray]:
    """(centre, real metres; rotation matrix)."""
    pos, quat = client.getBasePositionAndOrientation(body)
    return np.asarray(pos) / SCALING, np.asarray(client.getMatrixFromQuaternion(quat)).reshape(3, 3)


def arm_grasps(client, body: int, along_m: float, depth_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Tip positions (k, 3) and tool yaws (k,) that grasp each upward-pointing arm ``along_m`` from the centre,
    ``depth_m`` below the arm's axis, with the jaws opening across the arm (either sign of yaw works)."""
    centre, rot = jack_pose(client, body)
    tips, yaws = [], []
    for axis in np.concatenate([rot.T, -rot.T]):     # the six arm directions, world frame
        if axis[2] < 0.3:                            # arms pointing down or sideways cannot be reached from above
            continue
        point = centre + along_m * axis
        tips.append(point - np.array([0.0, 0.0, depth_m]))
        yaws.append(np.arctan2(axis[1], axis[0]) + np.pi / 2)
    return np.array(tips), np.array(yaws)


def lowest_point_below(client, body: int, point_m: np.ndarray) -> float:
    """How far (real metres) the jack's lowest point lies below ``point_m`` (e.g. the tip that holds it)."""
    centre, rot = jack_pose(client, body)
    ends = centre + JACK_ARM_LENGTH * np.concatenate([rot.T, -rot.T])
    return float(point_m[2] - (ends[:, 2].min() - JACK_ARM_RADIUS))


# ---------------------------------------------------------------------- trays
def make_colour_tray(client, centre_xy, colour, visual: bool = True) -> int:
    """A static open tray on the table, centred at ``centre_xy``; its floor's top is ``tray_floor_z()``.

    The floor's collision box reaches ``physics.FLOOR_COLLISION_DEPTH_M`` down into the table, as the needle tray's
    does, so a jack dropped onto the thin floor cannot pass through it within one physics step.
    """
    table = objects.TABLE_TOP_Z
    depth = physics.FLOOR_COLLISION_DEPTH_M
    outer = TRAY_INNER_HALF + TRAY_WALL
    wall_z = TRAY_FLOOR + TRAY_WALL_HEIGHT / 2
    walls = [((outer, TRAY_WALL / 2, TRAY_WALL_HEIGHT / 2), (0.0, TRAY_INNER_HALF + TRAY_WALL / 2, wall_z)),
             ((outer, TRAY_WALL / 2, TRAY_WALL_HEIGHT / 2), (0.0, -TRAY_INNER_HALF - TRAY_WALL / 2, wall_z)),
             ((TRAY_WALL / 2, outer, TRAY_WALL_HEIGHT / 2), (TRAY_INNER_HALF + TRAY_WALL / 2, 0.0, wall_z)),
             ((TRAY_WALL / 2, outer, TRAY_WALL_HEIGHT / 2), (-TRAY_INNER_HALF - TRAY_WALL / 2, 0.0, wall_z))]
    floor_visual = ((outer, outer, TRAY_FLOOR / 2), (0.0, 0.0, TRAY_FLOOR / 2))
    floor_collision = ((outer, outer, (TRAY_FLOOR + depth) / 2), (0.0, 0.0, (TRAY_FLOOR - depth) / 2))

    def scaled(parts):
        return ([(np.asarray(h) * SCALING).tolist() for h, _ in parts],
                [(np.asarray(c) * SCALING).tolist() for _, c in parts])

    half, centres = scaled([floor_collision] + walls)
    col = client.createCollisionShapeArray([pb.GEOM_BOX] * 5, halfExtents=half, collisionFramePositions=centres)
    vis = -1
    if visual:
        half, centres = scaled([floor_visual] + walls)
        vis = client.createVisualShapeArray([pb.GEOM_BOX] * 5, halfExtents=half, visualFramePositions=centres,
                                            rgbaColors=[colour] * 5)
    body = client.createMultiBody(0.0, col, vis, (np.array([centre_xy[0], centre_xy[1], table]) * SCALING).tolist(),
                                  useMaximalCoordinates=True)
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION, activationState=pb.ACTIVATION_STATE_SLEEP)
    return body


def move_tray(client, body: int, centre_xy) -> None:
    client.resetBasePositionAndOrientation(
        body, (np.array([centre_xy[0], centre_xy[1], objects.TABLE_TOP_Z]) * SCALING).tolist(), [0, 0, 0, 1])


def tray_floor_z() -> float:
    return objects.TABLE_TOP_Z + TRAY_FLOOR


def tray_wall_top_z() -> float:
    return tray_floor_z() + TRAY_WALL_HEIGHT

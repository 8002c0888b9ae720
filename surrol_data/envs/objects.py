"""Scene objects built from primitives (boxes, capsules), with the reference's dimensions and masses.

Sizes are given in real millimetres/metres and scaled to the simulation here. Every builder takes the
client explicitly and returns the PyBullet body id.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import instrument_geometry, physics
from surrol_data.envs.psm import matrix_to_quat
from surrol_data.envs.units import SCALING

GREY = (0.75, 0.75, 0.75, 1.0)
DARK = (0.25, 0.25, 0.28, 1.0)
TABLE_COLOUR = (0.62, 0.52, 0.42, 1.0)
PAD_COLOUR = (0.85, 0.45, 0.45, 1.0)
NEEDLE_COLOUR = (0.85, 0.85, 0.9, 1.0)

# Table: collision box 0.416 × 0.538 × 0.05 m, top at z = 0.675 m.
TABLE_CENTRE = np.array([0.5, 0.0, 0.65])
TABLE_HALF_EXTENTS = np.array([0.208, 0.269, 0.025])
TABLE_TOP_Z = 0.675

# Tray with pad (NeedleReach/NeedlePick): base 120 × 196 × 0.362 mm, walls 22 mm tall, pad 101 × 170 × 5.2 mm.
TRAY_ORIGIN = np.array([0.55, 0.0, 0.6751])
PAD_TOP_Z = TRAY_ORIGIN[2] + 0.0036 + 0.0026
# Tray without pad (GauzeRetrieve) sits 3 mm higher; its floor is the top of the 0.362 mm base.
BARE_TRAY_ORIGIN = np.array([0.55, 0.0, 0.6781])
BARE_TRAY_FLOOR_Z = BARE_TRAY_ORIGIN[2] + 0.000181

# Gauze: collision box 4 × 2 × 3 mm (x × y × z), 50 g; drawn as the reference's flat 15.2 × 25.5 × 2.5 mm pad.
GAUZE_HALF_EXTENTS = np.array([0.002, 0.001, 0.0015])
GAUZE_VISUAL_HALF_EXTENTS = np.array([0.0076, 0.01275, 0.00125])
GAUZE_MASS = 0.05
GAUZE_COLOUR = (0.95, 0.95, 0.92, 1.0)

# Needle: half circle of radius 20 mm opening towards +x of its frame, wire radius 0.62 mm, 10 g.
NEEDLE_RADIUS = 0.020
NEEDLE_WIRE_RADIUS = 0.00062
NEEDLE_MASS = 0.01
NEEDLE_SEGMENTS = 6   # even: a capsule joint sits exactly at the mid-arc waypoint; each capsule costs ~0.15 ms at reset
NEEDLE_COM = np.array([-2 * NEEDLE_RADIUS / np.pi, 0.0, 0.0])
# Waypoints in the needle frame (metres): 0 = arc centre, 1 = arc midpoint, 2/3 and 4/5 symmetric pairs.
NEEDLE_WAYPOINTS = np.array([
    [0.0, 0.0, 0.0],
    [-0.020, 0.0, 0.0],
    [-0.0141, -0.0141, 0.0], [-0.0141, 0.0141, 0.0],
    [-0.0100, -0.0173, 0.0], [-0.0100, 0.0173, 0.0],
])


def _box(client, half_extents_m, colour, mass=0.0, position_m=(0, 0, 0), friction=physics.OBJECT_FRICTION,
         visual: bool = True) -> int:
    he = np.asarray(half_extents_m) * SCALING
    col = client.createCollisionShape(pb.GEOM_BOX, halfExtents=he.tolist())
    vis = client.createVisualShape(pb.GEOM_BOX, halfExtents=he.tolist(), rgbaColor=colour) if visual else -1
    body = client.createMultiBody(mass, col, vis, (np.asarray(position_m) * SCALING).tolist())
    client.changeDynamics(body, -1, lateralFriction=friction)
    return body


def spawn_rigid_object(client, spec: dict, mass: float, inertia) -> int:
    """A fresh free object from ``spec`` (``createMultiBody`` arguments) with the objects' friction, its own mass
    and inertia diagonal (scaled units), allowed to sleep once it rests (its contacts then cost nothing)."""
    body = client.createMultiBody(**spec)
    # The mass is restated because PyBullet zeroes it when only the inertia of a rigid body is changed.
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION, spinningFriction=0.001,
                          rollingFriction=0.0, mass=mass, localInertiaDiagonal=list(inertia),
                          activationState=pb.ACTIVATION_STATE_ENABLE_SLEEPING)
    return body


def make_table(client, visual: bool = True) -> int:
    return _box(client, TABLE_HALF_EXTENTS, TABLE_COLOUR, position_m=TABLE_CENTRE, visual=visual)


# A rim on the table around the tool tip's clip box, for scenes whose objects lie loose on the table: a jack pushed
# by the blades' sides leads the clipped tip by its own reach, and ended up to 8.4 mm beyond the box (PickAndPlace,
# bang-bang seed 2), out of the tool's reach. Its inner faces stand on the box's edges; as tall as the colour trays'.
RIM_HEIGHT = 0.007
RIM_THICKNESS = 0.002
RIM_COLOUR = (0.55, 0.55, 0.58, 1.0)


def make_rim(client, box_xy, visual: bool = True) -> int:
    """A static rim standing on the table, its four walls' inner faces on the edges of ``box_xy`` ([[x0, x1], [y0,
    y1]], real metres)."""
    (x0, x1), (y0, y1) = box_xy
    t, h = RIM_THICKNESS / 2, RIM_HEIGHT / 2
    cx, cy, ox, oy = (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2 + 2 * t, (y1 - y0) / 2
    walls = [((ox, t, h), (0.0, oy + t, h)), ((ox, t, h), (0.0, -oy - t, h)),
             ((t, oy, h), (ox - t, 0.0, h)), ((t, oy, h), (-ox + t, 0.0, h))]
    half = [(np.asarray(e) * SCALING).tolist() for e, _ in walls]
    centres = [(np.asarray(c) * SCALING).tolist() for _, c in walls]
    col = client.createCollisionShapeArray([pb.GEOM_BOX] * 4, halfExtents=half, collisionFramePositions=centres)
    vis = client.createVisualShapeArray([pb.GEOM_BOX] * 4, halfExtents=half, visualFramePositions=centres,
                                        rgbaColors=[RIM_COLOUR] * 4) if visual else -1
    body = client.createMultiBody(0.0, col, vis, (np.array([cx, cy, TABLE_TOP_Z]) * SCALING).tolist(),
                                  useMaximalCoordinates=True)
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION, activationState=pb.ACTIVATION_STATE_SLEEP)
    return body


def make_tray(client, with_pad: bool, origin_m=TRAY_ORIGIN, visual: bool = True) -> int:
    """A static tray: thin base, four low walls and (optionally) a foam pad, as one compound body.

    The collision shapes of the base and the pad reach ``physics.FLOOR_COLLISION_DEPTH_M`` down into the table
    (static bodies do not collide with each other): an object driven into a 0.36 mm base or a 5 mm pad within
    one physics step is then still inside a thick box, and the solver pushes it back out of the top instead
    of through the bottom. Their visual shapes keep the reference's sizes.
    """
    mm = 1e-3
    depth = physics.FLOOR_COLLISION_DEPTH_M
    walls = [  # (half extents, centre) in metres, tray frame
        ((60 * mm, 1.5 * mm, 11 * mm), (0.0, 95 * mm, 11 * mm)),
        ((60 * mm, 1.5 * mm, 11 * mm), (0.0, -95 * mm, 11 * mm)),
        ((1.5 * mm, 98 * mm, 11 * mm), (58 * mm, 0.0, 11 * mm)),
        ((1.5 * mm, 98 * mm, 11 * mm), (-58 * mm, 0.0, 11 * mm)),
    ]
    base_top, pad_top = 0.181 * mm, 6.2 * mm
    visual_parts = [((60 * mm, 98 * mm, 0.181 * mm), (0.0, 0.0, 0.0))] + walls
    collision_parts = [((60 * mm, 98 * mm, (base_top + depth) / 2), (0.0, 0.0, (base_top - depth) / 2))] + walls
    colours = [GREY] * 5
    if with_pad:
        visual_parts.append(((50.5 * mm, 85 * mm, 2.6 * mm), (0.0, 0.0, 3.6 * mm)))
        collision_parts.append(((50.5 * mm, 85 * mm, (pad_top + depth) / 2), (0.0, 0.0, (pad_top - depth) / 2)))
        colours.append(PAD_COLOUR)

    def scaled(parts):
        return ([(np.asarray(h) * SCALING).tolist() for h, _ in parts],
                [(np.asarray(c) * SCALING).tolist() for _, c in parts])

    n = len(collision_parts)
    half, centres = scaled(collision_parts)
    col = client.createCollisionShapeArray([pb.GEOM_BOX] * n, halfExtents=half, collisionFramePositions=centres)
    vis = -1
    if visual:
        half, centres = scaled(visual_parts)
        vis = client.createVisualShapeArray([pb.GEOM_BOX] * n, halfExtents=half, visualFramePositions=centres,
                                            rgbaColors=colours)
    body = client.createMultiBody(0.0, col, vis, (np.asarray(origin_m) * SCALING).tolist())
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION)
    return body


@dataclass(frozen=True)
class NeedleGeometry:
    positions: list      # capsule centres (scaled, needle frame)
    orientations: list   # capsule orientations (quaternions): capsule z along the arc tangent
    length: float        # capsule cylinder length (scaled)


def _needle_geometry(client) -> NeedleGeometry:
    # Capsules whose ends meet on the arc; the arc spans angles 90°..270° (from +y through −x to −y).
    angles = np.linspace(np.pi / 2, 3 * np.pi / 2, NEEDLE_SEGMENTS + 1)
    pts = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1) * NEEDLE_RADIUS * SCALING
    positions, orientations = [], []
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        positions.append(((a + b) / 2).tolist())
        # Rotate the capsule's z axis onto the chord direction (a rotation about world z then x).
        yaw = np.arctan2(d[1], d[0])
        orientations.append(client.getQuaternionFromEuler([0.0, np.pi / 2, yaw]))
    length = float(np.linalg.norm(pts[1] - pts[0]))
    return NeedleGeometry(positions, orientations, length)


def needle_spec(client, visual: bool = True) -> dict:
    """Shapes and mass of the needle as ``createMultiBody`` arguments (reusable to respawn the body)."""
    g = _needle_geometry(client)
    n = len(g.positions)
    r = NEEDLE_WIRE_RADIUS * SCALING
    col = client.createCollisionShapeArray([pb.GEOM_CAPSULE] * n, radii=[r] * n, lengths=[g.length] * n,
                                           collisionFramePositions=g.positions,
                                           collisionFrameOrientations=g.orientations)
    # The look is a smooth tapered tube (instrument_geometry's mesh); the collision keeps its few capsules.
    vis = instrument_geometry.needle_visual_shape(client, SCALING, NEEDLE_COLOUR) if visual else -1
    # The centre of mass sits on the symmetry axis at 2R/π from the arc centre; PyBullet reports the base
    # pose at the centre of mass, so use set_needle_pose/needle_pose to speak in needle-frame terms.
    return dict(baseMass=NEEDLE_MASS, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis,
                basePosition=[0, 0, 0], baseInertialFramePosition=(NEEDLE_COM * SCALING).tolist())


def respawn_needle(client, spec: dict, old_body: int = -1) -> int:
    """A fresh needle body from ``spec`` (see :func:`needle_spec`), replacing ``old_body`` if there is one."""
    if old_body >= 0:
        client.removeBody(old_body)
    body = client.createMultiBody(**spec)
    configure_needle(client, body)
    return body


def configure_needle(client, body: int) -> None:
    # A needle at rest may sleep (contacts woken by the jaws or the grasp); most steps it just lies on the
    # pad, and skipping its ten capsule contacts makes a control step ~25 % cheaper.
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION, rollingFriction=0.0,
                          spinningFriction=0.001, activationState=pb.ACTIVATION_STATE_ENABLE_SLEEPING)


def set_needle_pose(client, body: int, position_m, yaw: float) -> None:
    """Place the needle frame (arc centre) at ``position_m`` with heading ``yaw``, at rest."""
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    com = (np.asarray(position_m) + rot @ NEEDLE_COM) * SCALING
    client.resetBasePositionAndOrientation(body, com.tolist(), client.getQuaternionFromEuler([0, 0, yaw]))
    client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


def set_needle_frame(client, body: int, position_m, rotation: np.ndarray) -> None:
    """Place the needle frame (arc centre) at ``position_m`` with any orientation (3×3 rotation), at rest."""
    com = (np.asarray(position_m) + rotation @ NEEDLE_COM) * SCALING
    client.resetBasePositionAndOrientation(body, com.tolist(), matrix_to_quat(rotation))
    client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


def needle_pose(client, body: int) -> tuple[np.ndarray, np.ndarray]:
    """(needle-frame origin in real metres, rotation matrix)."""
    com, quat = client.getBasePositionAndOrientation(body)
    rot = np.asarray(client.getMatrixFromQuaternion(quat)).reshape(3, 3)
    return np.asarray(com) / SCALING - rot @ NEEDLE_COM, rot


def needle_rest_height() -> float:
    """Needle-frame z (real metres) when the needle lies flat on the pad."""
    return PAD_TOP_Z + NEEDLE_WIRE_RADIUS


def gauze_spec(client, visual: bool = True) -> dict:
    """Shapes and mass of the gauze as ``createMultiBody`` arguments (reusable to respawn the body)."""
    col = client.createCollisionShape(pb.GEOM_BOX, halfExtents=(GAUZE_HALF_EXTENTS * SCALING).tolist())
    vis = client.createVisualShape(pb.GEOM_BOX, halfExtents=(GAUZE_VISUAL_HALF_EXTENTS * SCALING).tolist(),
                                   rgbaColor=GAUZE_COLOUR) if visual else -1
    return dict(baseMass=GAUZE_MASS, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis, basePosition=[0, 0, 0])


def configure_gauze(client, body: int) -> None:
    # Resting gauze may sleep until the jaws touch it: its box-on-tray contact is then free.
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION, rollingFriction=0.0,
                          spinningFriction=0.001, activationState=pb.ACTIVATION_STATE_ENABLE_SLEEPING)


def gauze_rest_height() -> float:
    """Gauze centre z (real metres) when it lies on the bare tray's floor."""
    return BARE_TRAY_FLOOR_Z + GAUZE_HALF_EXTENTS[2]


def make_goal_marker(client, radius_m: float = 0.003, colour=(0.1, 0.9, 0.1, 0.8), visual: bool = True) -> int:
    """The green goal sphere, a body that only shows (no collision shape); -1 in a world that never renders, where
    it would be nothing but a body PyBullet keeps in its collision world (an empty collider whose bounds it updates
    and pairs every physics step)."""
    if not visual:
        return -1
    vis = client.createVisualShape(pb.GEOM_SPHERE, radius=radius_m * SCALING, rgbaColor=colour)
    return client.createMultiBody(0.0, -1, vis, [0, 0, 0])

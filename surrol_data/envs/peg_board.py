"""The FLS peg board and its hexagonal blocks, built from primitives (shared by PegTransfer and BiPegTransfer).

Geometry follows the reference assets (real millimetres):

* board: a 103 × 154 × 22 mm box whose centre is the board origin, with 12 pegs (cylinders r = 1 mm,
  28 mm long) centred 22 mm above the origin, i.e. 25 mm of each peg stands above the board top.
* block: 14.8 × 17.0 × 14.6 mm, 10 g. That bounding box is a regular hexagon with 14.8 mm across the
  flats (17.09 mm across the corners), so a block is a hexagonal "nut": six wall boxes around a hexagonal
  hole of 9 mm across the flats that the peg passes through. The block frame's origin is the hole centre at
  mid-height (also its centre of mass); the flats face 0°, ±60°, ±120°, 180° of the block frame, and the
  reference's three waypoints lie 5 mm from the centre towards 180° and ±60°, inside the walls.

Why this hole size: the jaws open 40° (each blade 20°), so an open blade's tip reaches 4.8 mm inwards of the
tool axis. A tool straddling a wall must stay far enough from the peg that this blade misses it, which puts
the tool axis near the wall's outer face (:data:`GRASP_RADIUS`); the wall must then be thin enough that
the inner blade enters the hole. A 2.9 mm wall (4.5 mm → 7.4 mm from the centre) satisfies both with about
half a millimetre to spare; the peg has 3.5 mm of play in the hole, so a block released over a peg threads.

Positions are real metres in the world frame; each builder takes the client explicitly. The board and its
pegs are one static compound body (no contact pairs among its parts, none with the table); resting blocks
sleep, so an untouched block costs nothing per physics step.

Typical use (what PegTransfer does)::

    board = make_peg_board(client)
    shape = block_collision_shape(client)
    spec = block_spec(client, shape, TARGET_RED)
    block = spawn_block(client, spec)                 # fresh body every reset (bit-exact determinism)
    place_block_on_peg(client, block, board, peg_index=7, yaw=0.2)
    board.peg_positions[0]                            # a goal: peg origin, world real metres
    tips, yaws = wall_grasps(client, block, depth_m=0.0025)   # oracle grasp candidates
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import objects, physics
from surrol_data.envs.units import SCALING

_MM = 1e-3

BOARD_ORIGIN = np.array([0.55, 0.0, 0.6861])
BOARD_HALF_EXTENTS = np.array([51.5, 77.0, 11.0]) * _MM
BOARD_COLOUR = (0.9, 0.9, 0.85, 1.0)
PEG_COLOUR = (0.45, 0.45, 0.5, 1.0)
PEG_RADIUS = 1.0 * _MM
PEG_LENGTH = 28.0 * _MM
PEG_CENTRE_HEIGHT = 22.0 * _MM      # above the board origin
# Peg centres in the board frame (mm), reference numbering 1..12 → indices 0..11. Pegs 0–5 are the two
# upper rows (goal pegs of PegTransfer), 6–11 the lower cluster the blocks start on.
PEG_XY = np.array([
    [-30.0, 43.0], [-10.0, 43.0], [10.0, 43.0],
    [-30.0, 13.0], [-10.0, 13.0], [10.0, 13.0],
    [-33.0, -27.0], [13.0, -27.0],
    [-21.5, -7.1], [1.5, -7.1],
    [-21.5, -46.9], [1.5, -46.9],
]) * _MM
NUM_PEGS = len(PEG_XY)

BLOCK_MASS = 0.01
BLOCK_ACROSS_FLATS = 14.8 * _MM
BLOCK_HEIGHT = 14.6 * _MM
BLOCK_HOLE_INRADIUS = 4.5 * _MM
BLOCK_OUTER_INRADIUS = BLOCK_ACROSS_FLATS / 2
BLOCK_WALL_NORMALS = np.deg2rad([0.0, 60.0, 120.0, 180.0, 240.0, 300.0])
# Reference waypoints (block frame, metres): 0 at (-5, 0), 1 and 2 at ±120° from it on a 5 mm circle.
BLOCK_WAYPOINTS = np.array([[-5.0, 0.0, 0.0], [2.5, 4.33, 0.0], [2.5, -4.33, 0.0]]) * _MM
# Tool axis distance from the block centre when grasping a wall with the jaws opening radially: the open
# inner blade then clears a centred peg by 0.9 mm, and the closed outer blade lies 0.7 mm from the outer face.
GRASP_RADIUS = 6.7 * _MM
TARGET_RED = (0.85, 0.12, 0.1, 1.0)
OTHER_BLUE = (0.25, 0.45, 0.85, 1.0)


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------------- board
@dataclass(frozen=True)
class PegBoard:
    body: int
    origin: np.ndarray          # board origin, real metres

    @property
    def top_z(self) -> float:
        return float(self.origin[2] + BOARD_HALF_EXTENTS[2])

    @property
    def peg_positions(self) -> np.ndarray:
        """(12, 3) peg centres ("peg origins", the PegTransfer goals), world real metres."""
        return peg_positions(self.origin)

    @property
    def peg_top_z(self) -> float:
        return float(self.origin[2] + PEG_CENTRE_HEIGHT + PEG_LENGTH / 2)

    def block_rest_height(self) -> float:
        """Block-frame z (real metres) of a block standing on the board."""
        return self.top_z + BLOCK_HEIGHT / 2


def peg_positions(origin_m=BOARD_ORIGIN) -> np.ndarray:
    o = np.asarray(origin_m, dtype=np.float64)
    z = np.full((NUM_PEGS, 1), o[2] + PEG_CENTRE_HEIGHT)
    return np.hstack([o[:2] + PEG_XY, z])


def make_peg_board(client, origin_m=BOARD_ORIGIN, visual: bool = True) -> PegBoard:
    """The static board with its 12 pegs as one compound body."""
    origin = np.asarray(origin_m, dtype=np.float64)
    S = SCALING
    types = [pb.GEOM_BOX] + [pb.GEOM_CYLINDER] * NUM_PEGS
    half = [(BOARD_HALF_EXTENTS * S).tolist()] + [[0.0, 0.0, 0.0]] * NUM_PEGS
    radii = [0.0] + [PEG_RADIUS * S] * NUM_PEGS
    lengths = [0.0] + [PEG_LENGTH * S] * NUM_PEGS
    frames = [[0.0, 0.0, 0.0]] + [[x * S, y * S, PEG_CENTRE_HEIGHT * S] for x, y in PEG_XY]
    col = client.createCollisionShapeArray(types, halfExtents=half, radii=radii, lengths=lengths,
                                           collisionFramePositions=frames)
    vis = client.createVisualShapeArray(types, halfExtents=half, radii=radii, lengths=lengths,
                                        visualFramePositions=frames,
                                        rgbaColors=[BOARD_COLOUR] + [PEG_COLOUR] * NUM_PEGS) if visual else -1
    # A static rigid body (maximal coordinates) marked asleep: Bullet then skips its contact pairs with
    # sleeping blocks altogether. As a fixed-base multibody, each resting block cost ~3 µs per physics step.
    body = client.createMultiBody(0.0, col, vis, (origin * S).tolist(), useMaximalCoordinates=True)
    client.changeDynamics(body, -1, lateralFriction=physics.PEG_BOARD_FRICTION,
                          activationState=pb.ACTIVATION_STATE_SLEEP)
    return PegBoard(body=body, origin=origin)


# ---------------------------------------------------------------------- blocks
def _block_walls() -> tuple[list, list, list]:
    """Half extents, centres and orientations (scaled, block frame) of the six wall boxes."""
    thickness = BLOCK_OUTER_INRADIUS - BLOCK_HOLE_INRADIUS
    centre_r = (BLOCK_OUTER_INRADIUS + BLOCK_HOLE_INRADIUS) / 2
    # A box as long as the outer hexagon's side: its outer corners are the hexagon's vertices, and the
    # overlap of neighbouring boxes fills each corner.
    side = 2 * BLOCK_OUTER_INRADIUS * np.tan(np.pi / 6)
    half = (np.array([thickness / 2, side / 2, BLOCK_HEIGHT / 2]) * SCALING).tolist()
    halves, centres, quats = [], [], []
    for a in BLOCK_WALL_NORMALS:
        halves.append(half)
        centres.append((np.array([np.cos(a), np.sin(a), 0.0]) * centre_r * SCALING).tolist())
        quats.append(pb.getQuaternionFromEuler([0.0, 0.0, float(a)]))
    return halves, centres, quats


def block_collision_shape(client) -> int:
    halves, centres, quats = _block_walls()
    n = len(halves)
    return client.createCollisionShapeArray([pb.GEOM_BOX] * n, halfExtents=halves,
                                            collisionFramePositions=centres, collisionFrameOrientations=quats)


def block_spec(client, collision_shape: int, colour=TARGET_RED, visual: bool = True) -> dict:
    """``createMultiBody`` arguments of one block (reuse to respawn fresh bodies; see :func:`spawn_block`)."""
    vis = -1
    if visual:
        halves, centres, quats = _block_walls()
        n = len(halves)
        vis = client.createVisualShapeArray([pb.GEOM_BOX] * n, halfExtents=halves, visualFramePositions=centres,
                                            visualFrameOrientations=quats, rgbaColors=[colour] * n)
    # A multibody base, not a maximal-coordinates rigid body: PyBullet can put only the former to sleep on
    # request, and a sleeping block's contacts with the sleeping board are skipped (see make_peg_board).
    return dict(baseMass=BLOCK_MASS, baseCollisionShapeIndex=collision_shape, baseVisualShapeIndex=vis,
                basePosition=[0.0, 0.0, 0.0])


def _block_inertia() -> list[float]:
    # A thick-walled tube between the hole and the outer inradius stands in for the hexagonal ring; PyBullet
    # would otherwise take the compound's bounding box, overstating the inertia of a ring that is mostly hole.
    r1, r2 = BLOCK_HOLE_INRADIUS * SCALING, BLOCK_OUTER_INRADIUS * SCALING
    h = BLOCK_HEIGHT * SCALING
    izz = BLOCK_MASS * (r1 ** 2 + r2 ** 2) / 2
    ixx = BLOCK_MASS * (3 * (r1 ** 2 + r2 ** 2) + h ** 2) / 12
    return [ixx, ixx, izz]


def spawn_block(client, spec: dict) -> int:
    """A fresh block body from ``spec``, allowed to sleep once it rests (its contacts then cost nothing)."""
    return objects.spawn_rigid_object(client, spec, BLOCK_MASS, _block_inertia())


def place_block_on_peg(client, body: int, board: PegBoard, peg_index: int, yaw: float) -> None:
    """Thread the block on a peg, standing on the board, hole centred on the peg, at rest."""
    if not 0 <= peg_index < NUM_PEGS:
        raise ValueError(f"peg_index must be in 0..{NUM_PEGS - 1}, got {peg_index}")
    x, y = board.peg_positions[peg_index, :2]
    position = np.array([x, y, board.block_rest_height()]) * SCALING
    client.resetBasePositionAndOrientation(body, position.tolist(), pb.getQuaternionFromEuler([0, 0, yaw]))
    client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


def block_pose(client, body: int) -> tuple[np.ndarray, np.ndarray]:
    """(block-frame origin = hole centre at mid-height, real metres; rotation matrix)."""
    pos, quat = client.getBasePositionAndOrientation(body)
    return np.asarray(pos) / SCALING, np.asarray(client.getMatrixFromQuaternion(quat)).reshape(3, 3)


def block_yaw(rotation: np.ndarray) -> float:
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


def block_waypoints(client, body: int) -> np.ndarray:
    """(3, 3) world positions (real metres) of the reference's block waypoints 0, 1, 2."""
    pos, rot = block_pose(client, body)
    return pos + BLOCK_WAYPOINTS @ rot.T


def wall_grasps(client, body: int, depth_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Tip positions (6, 3) and tool yaws (6,) that straddle each wall with the jaws opening radially.

    The tip sits :data:`GRASP_RADIUS` from the hole centre, ``depth_m`` below the block's top face; a tool
    yaw points the jaw-opening direction along the wall normal (either sign works, the jaw is symmetric).
    """
    pos, rot = block_pose(client, body)
    top = pos + rot @ np.array([0.0, 0.0, BLOCK_HEIGHT / 2])
    normals = np.stack([np.cos(BLOCK_WALL_NORMALS), np.sin(BLOCK_WALL_NORMALS), np.zeros(6)], axis=1) @ rot.T
    tips = top + GRASP_RADIUS * normals - np.array([0.0, 0.0, depth_m])
    yaws = np.arctan2(normals[:, 1], normals[:, 0])
    return tips, yaws

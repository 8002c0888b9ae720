"""The ring peg board of PegBoard, built from primitives: a floor board with upright pegs, a vertical panel
with horizontal pegs, and a ring.

The exercise is the robotic-surgery curriculum's "Pegboard" (da Vinci Skills Simulator, Pegboard level 2:
"transferring rings from a pegboard onto 2 pegs on the floor", Can Urol Assoc J 2013;7(7-8):E520, Fig. 1A;
SurRoL-v2's ``ring_board.urdf`` / ``ring_peg.urdf`` / ``ring_tao.urdf``: two upright floor pegs and twelve
horizontal pegs on a vertical panel behind them, one ring). The reference assets are meshes sized for the
GUI (the panel stands ~80 mm tall, more than the PSM's 70 mm tip workspace); here the same layout is sized to
the PSM workspace and to the training kits' rubber rings (real millimetres):

* floor board: 100 × 90 × 4 mm on the table, three upright pegs (r = 1.5 mm, 15 mm above the board) in a
  row along x, 25 mm apart (the goal pegs; the dVSS floor has two, a third widens goal sampling);
* panel: 80 × 4 mm, 60 mm tall, standing on the board at the −y edge, with six horizontal pegs
  (r = 1.5 mm, 14 mm long, pointing +y) in two rows of three, 22 mm apart;
* ring: 12 mm mean diameter (inner 10, outer 14 mm), 2 mm thick, 3 g — a rubber O-ring of a transfer kit.
  The peg has 3.5 mm of play in the hole, so a ring lowered over a peg while tilted up to ~60° still
  threads, and a ring held upright (as it hangs on the panel) does not: the wrist must turn it.

The ring is twelve boxes around its circle (frame: centre, axis along local z; it lies flat at identity).
Positions are real metres in the world frame; builders take the client explicitly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import objects, physics
from surrol_data.envs.objects import TABLE_TOP_Z
from surrol_data.envs.shapes import convex_boxes
from surrol_data.envs.units import SCALING

_MM = 1e-3

BOARD_CENTRE_XY = np.array([0.55, 0.0])
BOARD_HALF_EXTENTS = np.array([50.0, 45.0, 2.0]) * _MM
BOARD_TOP_Z = TABLE_TOP_Z + 2 * BOARD_HALF_EXTENTS[2]
PEG_RADIUS = 1.5 * _MM
FLOOR_PEG_HEIGHT = 15.0 * _MM
FLOOR_PEG_XY = np.array([[0.525, 0.015], [0.550, 0.015], [0.575, 0.015]])
PANEL_HALF_EXTENTS = np.array([40.0, 2.0, 30.0]) * _MM
PANEL_CENTRE = np.array([0.55, -0.045 - PANEL_HALF_EXTENTS[1], BOARD_TOP_Z + PANEL_HALF_EXTENTS[2]])
PANEL_FACE_Y = PANEL_CENTRE[1] + PANEL_HALF_EXTENTS[1]
PANEL_PEG_LENGTH = 14.0 * _MM
# Panel peg axes (x, z), world metres: two rows of three.
PANEL_PEG_XZ = np.array([[x, z] for z in (0.712, 0.734) for x in (0.528, 0.550, 0.572)])
NUM_PANEL_PEGS = len(PANEL_PEG_XZ)

RING_MEAN_RADIUS = 6.0 * _MM
RING_WIDTH = 2.0 * _MM               # radial
RING_THICKNESS = 2.0 * _MM           # axial
RING_INNER_RADIUS = RING_MEAN_RADIUS - RING_WIDTH / 2
RING_OUTER_RADIUS = RING_MEAN_RADIUS + RING_WIDTH / 2
RING_MASS = 0.003
RING_SEGMENTS = 12
# Hanging on a panel peg, the ring's inner rim rests on the peg top: its centre is this far below the peg axis.
HANG_DROP = RING_INNER_RADIUS - PEG_RADIUS
RING_ON_PEG_Y = PANEL_FACE_Y + PANEL_PEG_LENGTH / 2   # hung halfway along the peg
BOARD_COLOUR = (0.93, 0.93, 0.9, 1.0)
PEG_COLOUR = (0.45, 0.45, 0.5, 1.0)
RING_COLOUR = (0.95, 0.55, 0.1, 1.0)

# Ring frame → hanging on a panel peg (axis along world y): rotate the flat ring about x by 90°.
HANGING = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class RingBoard:
    body: int

    @property
    def floor_pegs(self) -> np.ndarray:
        """(3, 3) floor peg bases (on the board top), world real metres."""
        return np.hstack([FLOOR_PEG_XY, np.full((len(FLOOR_PEG_XY), 1), BOARD_TOP_Z)])

    @property
    def floor_peg_top_z(self) -> float:
        return BOARD_TOP_Z + FLOOR_PEG_HEIGHT

    def hanging_centre(self, peg: int) -> np.ndarray:
        """Ring centre when it hangs on panel peg ``peg``."""
        x, z = PANEL_PEG_XZ[peg]
        return np.array([x, RING_ON_PEG_Y, z - HANG_DROP])


def resting_centre_z() -> float:
    """Ring centre height when it lies flat on the board (the goal's height)."""
    return BOARD_TOP_Z + RING_THICKNESS / 2


def make_ring_board(client, visual: bool = True) -> RingBoard:
    """Board, panel and all pegs as one static compound body (no contacts among its parts)."""
    S = SCALING
    quat_x = pb.getQuaternionFromEuler([-np.pi / 2, 0.0, 0.0])     # a cylinder's axis (z) turned onto +y
    parts = [  # (type, half extents, radius, length, centre, orientation)
        (pb.GEOM_BOX, BOARD_HALF_EXTENTS, 0.0, 0.0, [*BOARD_CENTRE_XY, TABLE_TOP_Z + BOARD_HALF_EXTENTS[2]],
         [0, 0, 0, 1]),
        (pb.GEOM_BOX, PANEL_HALF_EXTENTS, 0.0, 0.0, PANEL_CENTRE, [0, 0, 0, 1]),
    ]
    for x, y in FLOOR_PEG_XY:
        parts.append((pb.GEOM_CYLINDER, np.zeros(3), PEG_RADIUS, FLOOR_PEG_HEIGHT,
                      [x, y, BOARD_TOP_Z + FLOOR_PEG_HEIGHT / 2], [0, 0, 0, 1]))
    for x, z in PANEL_PEG_XZ:
        parts.append((pb.GEOM_CYLINDER, np.zeros(3), PEG_RADIUS, PANEL_PEG_LENGTH,
                      [x, PANEL_FACE_Y + PANEL_PEG_LENGTH / 2, z], quat_x))
    origin = np.array([*BOARD_CENTRE_XY, TABLE_TOP_Z])
    types = [p[0] for p in parts]
    half = [(np.asarray(p[1]) * S).tolist() for p in parts]
    radii = [p[2] * S for p in parts]
    lengths = [p[3] * S for p in parts]
    frames = [((np.asarray(p[4]) - origin) * S).tolist() for p in parts]
    quats = [list(p[5]) for p in parts]
    col = client.createCollisionShapeArray(types, halfExtents=half, radii=radii, lengths=lengths,
                                           collisionFramePositions=frames, collisionFrameOrientations=quats)
    vis = -1
    if visual:
        colours = [BOARD_COLOUR, BOARD_COLOUR] + [PEG_COLOUR] * (len(parts) - 2)
        vis = client.createVisualShapeArray(types, halfExtents=half, radii=radii, lengths=lengths,
                                            visualFramePositions=frames, visualFrameOrientations=quats,
                                            rgbaColors=colours)
    body = client.createMultiBody(0.0, col, vis, (origin * S).tolist(), useMaximalCoordinates=True)
    client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION,
                          activationState=pb.ACTIVATION_STATE_SLEEP)
    return RingBoard(body=body)


def ring_boxes(mean_radius: float, width: float, thickness: float,
               segments: int = RING_SEGMENTS) -> tuple[list, list, list]:
    """Half extents, centres and orientations (scaled, ring frame: axis along z) of a ring made of boxes."""
    outer = mean_radius + width / 2
    side = 2 * outer * np.tan(np.pi / segments)   # outer corners meet: no gaps
    half = (np.array([width / 2, side / 2, thickness / 2]) * SCALING).tolist()
    halves, centres, quats = [], [], []
    for a in np.arange(segments) * 2 * np.pi / segments:
        halves.append(half)
        centres.append((np.array([np.cos(a), np.sin(a), 0.0]) * mean_radius * SCALING).tolist())
        quats.append(pb.getQuaternionFromEuler([0.0, 0.0, float(a)]))
    return halves, centres, quats


def _ring_segments() -> tuple[list, list, list]:
    return ring_boxes(RING_MEAN_RADIUS, RING_WIDTH, RING_THICKNESS)


def ring_spec(client, visual: bool = True) -> dict:
    """``createMultiBody`` arguments of the ring (reused to spawn a fresh body every reset)."""
    halves, centres, quats = _ring_segments()
    n = len(halves)
    col = convex_boxes(client, halves, centres, quats)
    vis = client.createVisualShapeArray([pb.GEOM_BOX] * n, halfExtents=halves, visualFramePositions=centres,
                                        visualFrameOrientations=quats, rgbaColors=[RING_COLOUR] * n) if visual else -1
    return dict(baseMass=RING_MASS, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis, basePosition=[0, 0, 0])


def spawn_ring(client, spec: dict, old_body: int = -1) -> int:
    if old_body >= 0:
        client.removeBody(old_body)
    r1, r2, h = RING_INNER_RADIUS * SCALING, RING_OUTER_RADIUS * SCALING, RING_THICKNESS * SCALING
    # A thick-walled tube (not the compound's bounding box, which would overstate a ring that is mostly hole).
    izz = RING_MASS * (r1 ** 2 + r2 ** 2) / 2
    ixx = RING_MASS * (3 * (r1 ** 2 + r2 ** 2) + h ** 2) / 12
    return objects.spawn_rigid_object(client, spec, RING_MASS, [ixx, ixx, izz])


def set_ring_pose(client, body: int, centre_m, rotation: np.ndarray) -> None:
    from surrol_data.envs.psm import matrix_to_quat

    client.resetBasePositionAndOrientation(body, (np.asarray(centre_m) * SCALING).tolist(), matrix_to_quat(rotation))
    client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


def ring_pose(client, body: int) -> tuple[np.ndarray, np.ndarray]:
    """(ring centre, real metres; rotation matrix)."""
    pos, quat = client.getBasePositionAndOrientation(body)
    return np.asarray(pos) / SCALING, np.asarray(client.getMatrixFromQuaternion(quat)).reshape(3, 3)


def ring_tilt(rotation: np.ndarray) -> float:
    """Angle (rad) between the ring's axis and the vertical: 0 lying flat, π/2 hanging upright."""
    return float(np.arccos(min(1.0, abs(rotation[2, 2]))))

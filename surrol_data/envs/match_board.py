"""The match board: digit and letter blocks and a board with a groove shaped like each, built from boxes.

Geometry (real millimetres). The paper's MatchBoard ("pick up a digit or alphabet block and place it on groove
in the corresponding position") gives no sizes, and the reference's v2 assets are unscaled meshes (board 8
slots, pieces 0 1 2 4 5 6 a b c at ×0.03). Ours are drawn on a pixel grid, the way a stencil font is:

* **glyphs** are 3 × 5 pixels of 3.5 mm (blocks 10.5 × 17.5 mm, 5 mm thick). The pixel is our choice, set by
  the tool: a one-pixel stroke must fit between the jaws (blades 10.2 mm long opening 40°: 7 mm apart at
  their tips, 5.3 mm at 2 mm up the blade), with the open blades beside it inside the empty neighbouring pixel.
  The glyphs are ones whose half-turn is neither themselves nor another glyph on the board ("2" and "5" are
  their own half-turn in this font; "L" turned is "7"), so a block seats in its groove only the right way round.
* **grooves** are the glyph's pixels 3 mm deep in an 8 mm thick board, widened by 1.5 mm on every side: a
  block released within about 1.5 mm and 8° of its seat drops in (a person lining a block up by eye is that
  good; a tighter groove left our simulated experts' blocks on the edge). A block turned by more, or the wrong
  way round, rests on the board's top instead: the groove accepts its block only in the right orientation.
* **board** cells are 5 × 7 pixels (a one-pixel wall around each glyph), side by side.

Each builder takes the client explicitly; positions are real metres in the world frame. Glyph frames: x along
the glyph's rows (left to right), y up the glyph, origin at the glyph's centre (a block's frame origin is its
centre, mid-height).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import objects, physics
from surrol_data.envs.units import SCALING

_MM = 1e-3

PIXEL = 3.5 * _MM
BLOCK_HEIGHT = 5.0 * _MM
BLOCK_MASS = 0.005
GROOVE_DEPTH = 3.0 * _MM
GROOVE_CLEARANCE = 1.5 * _MM
BOARD_THICKNESS = 8.0 * _MM
CELL_PIXELS = (5, 7)               # glyph plus a one-pixel wall around it
BOARD_COLOUR = (0.93, 0.9, 0.8, 1.0)
BLOCK_COLOURS = {"L": (0.85, 0.2, 0.15, 1.0), "4": (0.2, 0.45, 0.85, 1.0), "F": (0.95, 0.7, 0.1, 1.0),
                 "C": (0.2, 0.65, 0.3, 1.0)}

# Rows top to bottom.
GLYPHS = {
    "L": ("X..", "X..", "X..", "X..", "XXX"),
    "4": ("X.X", "X.X", "XXX", "..X", "..X"),
    "F": ("XXX", "X..", "XX.", "X..", "X.."),
    "C": ("XXX", "X..", "X..", "X..", "XXX"),
}


def glyph_pixels(name: str) -> np.ndarray:
    """(k, 2) integer (column, row-from-bottom) of the glyph's filled pixels."""
    rows = GLYPHS[name]
    return np.array([(c, len(rows) - 1 - r) for r, line in enumerate(rows) for c, ch in enumerate(line) if ch == "X"])


def _pixel_centre(col_row, shape=(3, 5)) -> np.ndarray:
    """Centre (metres, glyph frame) of pixel (column, row-from-bottom) of a glyph grid of ``shape``."""
    c, r = col_row
    return np.array([(c - (shape[0] - 1) / 2) * PIXEL, (r - (shape[1] - 1) / 2) * PIXEL])


def glyph_half_turn_fits(name: str, other: str) -> bool:
    """Does ``name`` turned by 180° cover exactly the pixels of ``other``?"""
    p = glyph_pixels(name)
    turned = {(2 - c, 4 - r) for c, r in p}
    return turned == {tuple(x) for x in glyph_pixels(other)}


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@functools.cache
def grasp_pixel(name: str) -> tuple[np.ndarray, float]:
    """Where to grasp a block: the centre (glyph frame, metres) of the stroke pixel nearest the block's centre
    whose two neighbours across the stroke are empty (room for the open blades), and the jaw-opening direction's
    angle in the glyph frame (0: across x, π/2: across y)."""
    filled = {tuple(p) for p in glyph_pixels(name)}
    centroid = glyph_centroid(name)
    best = None
    for p in sorted(filled):
        for angle, (dc, dr) in ((0.0, (1, 0)), (np.pi / 2, (0, 1))):
            if (p[0] + dc, p[1] + dr) in filled or (p[0] - dc, p[1] - dr) in filled:
                continue
            d = float(np.linalg.norm(_pixel_centre(p) - centroid))
            if best is None or d < best[0] - 1e-9:
                best = (d, _pixel_centre(p), angle)
    if best is None:
        raise ValueError(f"glyph {name!r} has no stroke the jaws can close across")
    return _read_only(best[1]), best[2]


# ---------------------------------------------------------------------- blocks
# A block's collision shape, for the tasks that ask for it (GlyphBlockScene.MERGED_BLOCKS): its glyph's pixels
# merged into as few boxes as cover them exactly (True), or one box per pixel (False; always for the other tasks).
# The solid is the same; what changes is the contacts it keeps while resting: each child box on a floor keeps a
# manifold of 4 points, and PyBullet solves a resting block's contacts at every physics step even while it sleeps
# (a block lying in the drawer cost MatchBoardPanel ~130 µs of a ~180 µs physics step with 32 points, 8 boxes; the
# solver's iteration count made no difference, 10 or 50, nor did putting the block and the drawer to sleep).
# Merged, a glyph is 2–3 boxes (8–12 points). MatchBoardPanel: oracle steps/s ×1.57 (one process, 10 episodes × 5
# rounds alternating merged and not, medians), oracle success over seeds 0–99 still 100 %,
# benchmarks/physics_realism.py within its targets (30 episodes, deepest per column over its rows: 0.39 / 0.28 /
# 0.89 mm tool↔static / tool↔object / object↔static, 0.38 / 0.13 / 0.95 with a box per pixel). The mass, the centre
# of mass and the inertia (computed from the pixels) are unchanged.
MERGED_BLOCK_BOXES = True


@functools.cache
def glyph_boxes(name: str) -> tuple[tuple[int, int, int, int], ...]:
    """The glyph's pixels as disjoint rectangles (column, row-from-bottom of the lower-left pixel, columns, rows)
    that cover them exactly: greedily the largest rectangle of pixels not yet covered (ties: lowest row, then
    column), so that the block is made of few boxes."""
    left = {tuple(int(v) for v in p) for p in glyph_pixels(name)}
    boxes = []
    while left:
        best = None
        for c0, r0 in sorted(left, key=lambda p: (p[1], p[0])):
            for w in range(1, 4):
                for h in range(1, 6):
                    cells = {(c0 + i, r0 + j) for i in range(w) for j in range(h)}
                    if cells <= left and (best is None or w * h > best[2] * best[3]):
                        best = (c0, r0, w, h)
        boxes.append(best)
        c0, r0, w, h = best
        left -= {(c0 + i, r0 + j) for i in range(w) for j in range(h)}
    return tuple(boxes)


def _block_boxes(name: str, merged: bool) -> tuple[list, list]:
    """(half extents, centres) of the block's collision boxes (scaled, glyph frame): merged, or one per pixel."""
    if not merged:
        pixels = glyph_pixels(name)
        half = (np.array([PIXEL / 2, PIXEL / 2, BLOCK_HEIGHT / 2]) * SCALING).tolist()
        return [half] * len(pixels), [(np.array([*_pixel_centre(p), 0.0]) * SCALING).tolist() for p in pixels]
    halves, centres = [], []
    for c0, r0, w, h in glyph_boxes(name):
        lo, hi = _pixel_centre((c0, r0)), _pixel_centre((c0 + w - 1, r0 + h - 1))
        halves.append((np.array([w * PIXEL / 2, h * PIXEL / 2, BLOCK_HEIGHT / 2]) * SCALING).tolist())
        centres.append((np.array([*(lo + hi) / 2, 0.0]) * SCALING).tolist())
    return halves, centres


def block_spec(client, name: str, visual: bool = True, merged: bool = False) -> dict:
    """``createMultiBody`` arguments of the block shaped like glyph ``name``: its collision shape one box per pixel, or
    ``merged`` (see ``MERGED_BLOCK_BOXES``)."""
    halves, centres = _block_boxes(name, merged)
    n = len(halves)
    col = client.createCollisionShapeArray([pb.GEOM_BOX] * n, halfExtents=halves, collisionFramePositions=centres)
    vis = client.createVisualShapeArray([pb.GEOM_BOX] * n, halfExtents=halves, visualFramePositions=centres,
                                        rgbaColors=[BLOCK_COLOURS[name]] * n) if visual else -1
    # The centre of mass is the pixels' centroid, not the grid centre; PyBullet reports the base pose there,
    # so block_pose/place_block convert to and from the glyph frame.
    com = (np.array([*glyph_centroid(name), 0.0]) * SCALING).tolist()
    return dict(baseMass=BLOCK_MASS, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis, basePosition=[0, 0, 0],
                baseInertialFramePosition=com)


# The glyph's constants are asked for at every step (block_pose, the grasp point): computed once per glyph.
@functools.cache
def glyph_centroid(name: str) -> np.ndarray:
    """Centroid of the glyph's pixels (glyph frame, metres): the block's centre of mass."""
    return _read_only(np.mean([_pixel_centre(p) for p in glyph_pixels(name)], axis=0))


@functools.cache
def _centroid_3d(name: str) -> np.ndarray:
    return _read_only(np.array([*glyph_centroid(name), 0.0]))


def _block_inertia(name: str) -> list[float]:
    # Point masses at the pixel centres (about the centroid) plus each pixel's own box inertia.
    p = (np.array([_pixel_centre(q) for q in glyph_pixels(name)]) - glyph_centroid(name)) * SCALING
    m = BLOCK_MASS / len(p)
    a, h = PIXEL * SCALING, BLOCK_HEIGHT * SCALING
    own_xx, own_zz = m * (a * a + h * h) / 12, m * (2 * a * a) / 12
    ixx = float(np.sum(m * p[:, 1] ** 2) + len(p) * own_xx)
    iyy = float(np.sum(m * p[:, 0] ** 2) + len(p) * own_xx)
    izz = float(np.sum(m * (p ** 2).sum(axis=1)) + len(p) * own_zz)
    return [ixx, iyy, izz]


def spawn_block(client, spec: dict, name: str) -> int:
    """A fresh block body from ``spec``, allowed to sleep once it rests."""
    return objects.spawn_rigid_object(client, spec, BLOCK_MASS, _block_inertia(name))


# How far into the surface a block is laid. Bullet's box-box test reports a contact only once the boxes overlap: laid
# exactly on the table, a block fell freely through its first physics step (0.55 mm into the table), was pushed back
# out and bounced ~1 mm up; laid 0.02 mm in, it rests from the first step (0.002 mm deep).
_LAY_INTO_SURFACE_M = 2e-5


def place_block(client, body: int, name: str, xy, surface_z: float, yaw: float) -> None:
    """Lay block ``name`` flat on a surface at ``surface_z``, glyph centre at ``xy``, turned ``yaw``, at rest."""
    c, s = np.cos(yaw), np.sin(yaw)
    com = np.array([xy[0], xy[1], surface_z + BLOCK_HEIGHT / 2 - _LAY_INTO_SURFACE_M])
    com[:2] += np.array([[c, -s], [s, c]]) @ glyph_centroid(name)
    client.resetBasePositionAndOrientation(body, (com * SCALING).tolist(), pb.getQuaternionFromEuler([0.0, 0.0, yaw]))
    client.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])


def block_pose(client, body: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(glyph centre at mid-height, real metres; rotation matrix) of block ``name``."""
    return block_pose_from(*client.getBasePositionAndOrientation(body), name)


def block_pose_from(position, quaternion, name: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`block_pose` from the block body's base pose as PyBullet reports it."""
    rot = np.asarray(pb.getMatrixFromQuaternion(quaternion)).reshape(3, 3)
    return np.asarray(position) / SCALING - rot @ _centroid_3d(name), rot


def yaw_of(rotation: np.ndarray) -> float:
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


# ---------------------------------------------------------------------- board
# PyBullet builds a compound shape of at most 16 children (createCollisionShapeArray silently drops the rest), so
# the board is made of several static bodies of at most this many boxes each (static bodies never collide with
# each other, and a resting block touches only one or two of them).
_MAX_CHILDREN = 16


@dataclass(frozen=True)
class MatchBoard:
    bodies: tuple[int, ...]
    origin: np.ndarray             # board centre at the table top, real metres
    glyphs: tuple[str, ...]        # one groove per glyph, left to right along x

    @property
    def top_z(self) -> float:
        return float(self.origin[2] + BOARD_THICKNESS)

    def groove_centre(self, name: str) -> np.ndarray:
        """Where a block seated in the groove of ``name`` has its centre (real metres)."""
        i = self.glyphs.index(name)
        x = (i - (len(self.glyphs) - 1) / 2) * CELL_PIXELS[0] * PIXEL
        return np.array([self.origin[0] + x, self.origin[1], self.top_z - GROOVE_DEPTH + BLOCK_HEIGHT / 2])

    @property
    def half_extents(self) -> np.ndarray:
        return np.array([len(self.glyphs) * CELL_PIXELS[0] * PIXEL / 2, CELL_PIXELS[1] * PIXEL / 2])


def _groove_walls(name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(half extents, centre) in the cell frame (metres, z from the groove floor) of the wall around a groove:
    one box per non-glyph pixel of the cell, cut back by the clearance on each side that faces the glyph."""
    filled = {(c + 1, r + 1) for c, r in glyph_pixels(name)}          # cell coordinates (one-pixel border)
    walls = []
    for c in range(CELL_PIXELS[0]):
        for r in range(CELL_PIXELS[1]):
            if (c, r) in filled:
                continue
            lo, hi = np.zeros(2), np.zeros(2)   # how much to cut from the low and high side, per axis
            for axis in (0, 1):
                for sign, cut in ((-1, lo), (1, hi)):
                    step = np.array([0, 0])
                    step[axis] = sign
                    across = np.array([0, 0])
                    across[1 - axis] = 1
                    n = (c + step[0], r + step[1])
                    diagonals = [(n[0] + across[0], n[1] + across[1]), (n[0] - across[0], n[1] - across[1])]
                    if n in filled or any(d in filled for d in diagonals):
                        cut[axis] = GROOVE_CLEARANCE
            centre = _pixel_centre((c, r), CELL_PIXELS) + (lo - hi) / 2
            half = np.array([PIXEL / 2, PIXEL / 2]) - (lo + hi) / 2
            walls.append((np.array([half[0], half[1], GROOVE_DEPTH / 2]),
                          np.array([centre[0], centre[1], GROOVE_DEPTH / 2])))
    return walls


def make_match_board(client, origin_m, glyphs=tuple(GLYPHS), visual: bool = True) -> MatchBoard:
    """The static board (base plate and the walls around every groove) as one compound body at ``origin_m`` (its
    centre on the table top)."""
    origin = np.asarray(origin_m, dtype=np.float64)
    n = len(glyphs)
    floor = BOARD_THICKNESS - GROOVE_DEPTH
    cell_w = CELL_PIXELS[0] * PIXEL
    board_half = np.array([n * cell_w / 2, CELL_PIXELS[1] * PIXEL / 2])
    parts = [(np.array([*board_half, floor / 2]), np.array([0.0, 0.0, floor / 2]))]
    for i, name in enumerate(glyphs):
        x = (i - (n - 1) / 2) * cell_w
        for half, centre in _groove_walls(name):
            parts.append((half, centre + [x, 0.0, floor]))
    bodies = []
    for k in range(0, len(parts), _MAX_CHILDREN):
        chunk = parts[k:k + _MAX_CHILDREN]
        halves = [(h * SCALING).tolist() for h, _ in chunk]
        centres = [(c * SCALING).tolist() for _, c in chunk]
        col = client.createCollisionShapeArray([pb.GEOM_BOX] * len(chunk), halfExtents=halves,
                                               collisionFramePositions=centres)
        vis = client.createVisualShapeArray([pb.GEOM_BOX] * len(chunk), halfExtents=halves,
                                            visualFramePositions=centres,
                                            rgbaColors=[BOARD_COLOUR] * len(chunk)) if visual else -1
        body = client.createMultiBody(0.0, col, vis, (origin * SCALING).tolist(), useMaximalCoordinates=True)
        client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION,
                              activationState=pb.ACTIVATION_STATE_SLEEP)
        bodies.append(body)
    return MatchBoard(bodies=tuple(bodies), origin=origin, glyphs=tuple(glyphs))


def table_surface_z() -> float:
    return objects.TABLE_TOP_Z

"""The match-board panel's drawer: a cabinet whose drawer of three cells slides out on a prismatic joint with
friction, pulled by a post on its front. Built from boxes (real millimetres; sizes are our choice, as the paper
gives none: a drawer as wide as the match board, cells that take any glyph block whatever its turn, and a
handle post the jaws close across like a block's stroke).

* **cabinet** (static): a 71 × 39 mm cover plate 10–12 mm above the table on two side walls and a back wall;
  the episode's block lies on the cover.
* **drawer** (one link on a prismatic joint along −y, out 35 mm to a stop block under the cover): floor 0.5–1.5 mm above the table, walls to
  9.5 mm (the front to 12 mm, flush with the cover), two dividers making three cells 21.7 mm wide and 36 mm
  deep, and a 3 × 3 mm handle post standing 6 mm on the front wall. Mass 50 g.
* **friction**: the joint's motor holds it with ``FRICTION_N`` (scaled scene) at zero velocity, as PyBullet
  models dry joint friction: the drawer stays where it is left, and a tool that pulls on its handle harder than
  that drags it (the weld holds 20). It does not collide with the cabinet: the joint keeps it in its slot, and
  its contacts there would only cost time.

Positions are real metres in the world frame; every builder takes the client explicitly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs import objects, physics
from surrol_data.envs.units import SCALING

_MM = 1e-3

TRAVEL = 35.0 * _MM
LIMIT_BEYOND_STOP = 1.0 * _MM      # the joint's own limit, a backstop behind the stop block
# 0.4: the force-limited arm (physics.PSM_MAX_FORCE) must drag it by the handle; at 2.0 the arm's limits would have to be
# raised to where a poked object sinks into the board again.
FRICTION_N = 0.4
DRAWER_MASS = 0.05
CELLS = 3
COVER_TOP = 12.0 * _MM
FLOOR_TOP = 1.5 * _MM
HANDLE_TOP = 18.0 * _MM
HANDLE_HALF = 1.5 * _MM
_W, _D = 68.0 * _MM, 39.0 * _MM            # drawer outer width (x) and depth (y)
_WALL = 1.5 * _MM
_DIVIDER = 1.0 * _MM
CABINET_COLOUR = (0.55, 0.6, 0.68, 1.0)
DRAWER_COLOUR = (0.93, 0.9, 0.8, 1.0)
HANDLE_COLOUR = (0.3, 0.3, 0.35, 1.0)


def _cell_xs() -> np.ndarray:
    inner = _W - 2 * _WALL
    cell = (inner - (CELLS - 1) * _DIVIDER) / CELLS
    return np.array([-inner / 2 + cell / 2 + i * (cell + _DIVIDER) for i in range(CELLS)])


CELL_WIDTH = (_W - 2 * _WALL - (CELLS - 1) * _DIVIDER) / CELLS


@dataclass(frozen=True)
class Cabinet:
    body: int
    stop: int                     # the block under the cover that the drawer's back wall runs into when fully out
    centre: np.ndarray            # the closed drawer's centre at table height, real metres

    @property
    def cover_top_z(self) -> float:
        return float(self.centre[2] + COVER_TOP)

    @property
    def cover_y_range(self) -> tuple[float, float]:
        return float(self.centre[1] - _D / 2 + _WALL), float(self.centre[1] + _D / 2)

    def handle_position(self, opening: float) -> np.ndarray:
        """The handle post's top centre (real metres) with the drawer ``opening`` metres out."""
        return self.centre + np.array([0.0, -_D / 2 + _WALL / 2 - opening, HANDLE_TOP])

    def cell_floor_centre(self, cell: int, opening: float) -> np.ndarray:
        """Centre of cell ``cell``'s floor (real metres) with the drawer ``opening`` metres out."""
        return self.centre + np.array([_cell_xs()[cell], -opening, FLOOR_TOP])


def _boxes(client, parts, colours, visual: bool):
    half = [(np.asarray(h) * SCALING).tolist() for h, _ in parts]
    centres = [(np.asarray(c) * SCALING).tolist() for _, c in parts]
    col = client.createCollisionShapeArray([pb.GEOM_BOX] * len(parts), halfExtents=half,
                                           collisionFramePositions=centres)
    vis = client.createVisualShapeArray([pb.GEOM_BOX] * len(parts), halfExtents=half, visualFramePositions=centres,
                                        rgbaColors=colours) if visual else -1
    return col, vis


def make_cabinet(client, centre_m, visual: bool = True) -> Cabinet:
    """The static cabinet around the closed drawer whose centre (at table height) is ``centre_m``."""
    w, d = _W / 2 + 1.5 * _MM, _D / 2
    cover_z = COVER_TOP - 1.0 * _MM
    parts = [((w, d - _WALL / 2, 1.0 * _MM), (0.0, _WALL / 2, cover_z)),                     # cover (behind the front)
             ((0.5 * _MM, d, cover_z / 2), (w - 0.5 * _MM, 0.0, cover_z / 2)),               # side walls
             ((0.5 * _MM, d, cover_z / 2), (-w + 0.5 * _MM, 0.0, cover_z / 2)),
             ((w, 0.5 * _MM, cover_z / 2), (0.0, d + 0.5 * _MM, cover_z / 2))]               # back wall
    centre = np.asarray(centre_m, dtype=np.float64)
    bodies = []
    # The stop hangs from the cover between the last divider and the side wall, above the cell floor's
    # reach, where only the back wall passes: the drawer stops on contact, which is stiffer than PyBullet's
    # joint limit (a 6 N pull drove the drawer 9 mm past a limit at our time step).
    # Its +y face meets the back wall's −y face (drawer frame y = D/2 − wall) with the drawer TRAVEL out.
    stop_face = _D / 2 - _WALL - TRAVEL
    stop = [((5.0 * _MM, 0.4 * _MM, 1.0 * _MM), (_cell_xs()[-1], stop_face - 0.4 * _MM, COVER_TOP - 3.0 * _MM))]
    for group, colour in ((parts, CABINET_COLOUR), (stop, CABINET_COLOUR)):
        col, vis = _boxes(client, group, [colour] * len(group), visual)
        body = client.createMultiBody(0.0, col, vis, (centre * SCALING).tolist(), useMaximalCoordinates=True)
        client.changeDynamics(body, -1, lateralFriction=physics.OBJECT_FRICTION,
                              activationState=pb.ACTIVATION_STATE_SLEEP)
        bodies.append(body)
    return Cabinet(body=bodies[0], stop=bodies[1], centre=centre)


def drawer_spec(client, cabinet: Cabinet, visual: bool = True) -> dict:
    """``createMultiBody`` arguments of the drawer (a fixed, shapeless base at the cabinet; the drawer is link 0)."""
    w, d, wall = _W / 2, _D / 2, _WALL / 2
    low = (9.5 * _MM - FLOOR_TOP) / 2          # half height of the low walls and dividers
    front = (COVER_TOP - FLOOR_TOP) / 2
    handle = (HANDLE_TOP - COVER_TOP) / 2
    parts = [((w, d, 0.5 * _MM), (0.0, 0.0, 1.0 * _MM)),                                   # floor
             ((w, wall, front), (0.0, -d + wall, FLOOR_TOP + front)),                       # front
             ((w, wall, low), (0.0, d - wall, FLOOR_TOP + low)),                            # back
             ((wall, d, low), (w - wall, 0.0, FLOOR_TOP + low)),                            # sides
             ((wall, d, low), (-w + wall, 0.0, FLOOR_TOP + low))]
    for x in (_cell_xs()[:-1] + CELL_WIDTH / 2 + _DIVIDER / 2):
        parts.append(((_DIVIDER / 2, d - 2 * wall, low), (x, 0.0, FLOOR_TOP + low)))        # dividers
    parts.append(((HANDLE_HALF, HANDLE_HALF, handle), (0.0, -d + wall, COVER_TOP + handle)))  # handle post
    colours = [DRAWER_COLOUR] * (len(parts) - 1) + [HANDLE_COLOUR]
    col, vis = _boxes(client, parts, colours, visual)
    return dict(baseMass=0.0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=-1,
                basePosition=(cabinet.centre * SCALING).tolist(),
                linkMasses=[DRAWER_MASS], linkCollisionShapeIndices=[col], linkVisualShapeIndices=[vis],
                linkPositions=[[0.0, 0.0, 0.0]], linkOrientations=[[0.0, 0.0, 0.0, 1.0]],
                linkInertialFramePositions=[[0.0, 0.0, 0.0]], linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]],
                linkParentIndices=[0], linkJointTypes=[pb.JOINT_PRISMATIC], linkJointAxis=[[0.0, -1.0, 0.0]])


def spawn_drawer(client, spec: dict, cabinet: Cabinet) -> int:
    """A fresh drawer, closed, held by its joint friction, not colliding with the cabinet (its floor clears the
    table by half a millimetre)."""
    body = client.createMultiBody(**spec)
    # (Passing linearDamping or angularDamping in the same call makes PyBullet 3.2 drop the joint limits.)
    client.changeDynamics(body, 0, lateralFriction=physics.OBJECT_FRICTION, jointLowerLimit=0.0,
                          jointUpperLimit=(TRAVEL + LIMIT_BEYOND_STOP) * SCALING)
    apply_friction(client, body)
    client.setCollisionFilterPair(body, cabinet.body, 0, -1, 0)
    return body


def apply_friction(client, drawer: int) -> None:
    """The drawer's joint friction: a zero-velocity motor whose force limit is the friction force. PyBullet turns
    the limit into an impulse with the time step current at the call, so it is re-issued when the step changes."""
    client.setJointMotorControl2(drawer, 0, pb.VELOCITY_CONTROL, targetVelocity=0.0, force=FRICTION_N)


def opening(client, drawer: int) -> float:
    """How far the drawer is out (real metres)."""
    return float(pb.getJointState(drawer, 0, client._client)[0]) / SCALING   # (positional: asked for every step)


def table_z() -> float:
    return objects.TABLE_TOP_Z

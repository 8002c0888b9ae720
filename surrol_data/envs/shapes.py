"""Collision shapes that keep fast contacts: boxes built as convex hulls.

Bullet's box-box test reports only boxes that already overlap, so a box moving fast towards another box gets
no contact until it is inside it: a closed jaw (two box blades) swept down at full speed sank 1.6 mm into the
pad within one physics step, and a poked gauze sank 3–4 mm into the tray floor. The general convex test also
reports points a little apart (within Bullet's contact breaking threshold), and the solver then stops the
approach before the surfaces meet. The jaw blades and PegBoard's ring (a ring of boxes, pushed 2.6 mm into its
board by a spinning jaw) are therefore hulls; static boxes can stay boxes, since a hull against a box takes the
general test. Not every moving box: the general test adds contact points one per physics step, so a hull comes to
rest slowly where a box lands on its whole face at once (a hull gauze tumbled for seconds after a drop, a hull
MatchBoard block laid half-turned over its groove tipped 40° into it); a held box pressed on a floor is kept from
sinking by the sub-steps instead (adaptive_steps.SubstepPlanner._pressed_hold_refinement).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from surrol_data.envs.physics import pb  # physics imports pybullet quietly

# PyBullet's collision margin of a convex hull (scaled units): its surface lies this far outside the vertices.
HULL_MARGIN = 0.001
# A unit cube's vertices (±1), which a compound's children scale into boxes (PyBullet's createCollisionShapeArray
# takes a mesh only as a file; a convex body's mesh is loaded as its hull, with the margin above).
_UNIT_CUBE = str(Path(__file__).with_name("hull_cube.obj"))


def convex_box(client, half_extents, centre=(0.0, 0.0, 0.0)) -> int:
    """A box collision shape (scaled half extents, centre in the link frame) as a convex hull: the same faces
    (the vertices leave room for the hull's margin), edges rounded by the margin."""
    h = np.asarray(half_extents, float) - HULL_MARGIN
    if np.any(h <= 0):
        raise ValueError(f"convex_box: half extents {list(half_extents)} must exceed the hull margin {HULL_MARGIN}")
    c = np.asarray(centre, float)
    vertices = [(np.array(signs) * h + c).tolist() for signs in itertools.product((-1, 1), repeat=3)]
    return client.createCollisionShape(pb.GEOM_MESH, vertices=vertices)


def convex_boxes(client, half_extents, centres, orientations=None) -> int:
    """A compound collision shape of boxes (scaled half extents and centres, optional quaternions, in the body frame),
    each a convex hull as in :func:`convex_box`."""
    h = np.asarray(half_extents, float) - HULL_MARGIN
    if np.any(h <= 0):
        raise ValueError(f"convex_boxes: every half extent must exceed the hull margin {HULL_MARGIN}")
    n = len(h)
    extra = {} if orientations is None else {"collisionFrameOrientations": [list(q) for q in orientations]}
    return client.createCollisionShapeArray([pb.GEOM_MESH] * n, fileNames=[_UNIT_CUBE] * n,
                                            meshScales=h.tolist(), collisionFramePositions=[list(c) for c in centres],
                                            **extra)

"""What the instruments and the needle look like: one definition of their visual parts for every renderer.

The PSM carries a da Vinci EndoWrist-style needle driver, modelled here from primitives (no third-party meshes):

* the shaft, 8 mm across (the EndoWrist's diameter), black, with a steel sleeve at its distal end;
* the proximal clevis: two steel prongs at the end of the shaft holding the wrist-pitch pin;
* the wrist link (pitch axis → yaw axis, ``kinematics.WRIST_LENGTH``) with a hub round the pitch pin and the
  distal clevis holding the yaw pin;
* two jaw blades, 10.2 mm long (``kinematics.TIP_LENGTH``), each on its own jaw joint, so they open and close
  with ``jaw_angle``: a wide heel, a narrower distal half, and a darker grip insert on the inner face.

The needle is a smooth arc (``NEEDLE_VISUAL_SEGMENTS`` short capsules whose rounded ends hide the joints)
tapering to its point over the last ``NEEDLE_TAPER`` of its length (the 6-capsule collision shape is unchanged).

These parts become the PyBullet *visual* shapes of the bodies (:func:`visual_shape_array`), so TinyRenderer draws
them, and the Panda3D mirror and the Rerun meshes read them back from PyBullet — one geometry for the three.
Collision shapes are built elsewhere (``psm.py``, ``objects.py``) and do not depend on this module: the physics
is the same whatever the instruments look like.

Frames (the PSM's link frames, :mod:`surrol_data.envs.psm`): tool roll (link 3): origin on the wrist-pitch axis,
z along the shaft towards the tip, pitch axis = y. Wrist pitch (link 4): z = pitch axis, x along the wrist to
the yaw axis. Jaws (links 6, 7): origin on the yaw axis (z), blades along +y, blade ``s`` opening towards s·x.
Sizes in real metres; :func:`visual_shape_array` scales them to the scene.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from surrol_data.envs.physics import pb

SHAFT_RADIUS_M = 0.004      # 8 mm EndoWrist shaft
SHAFT_LENGTH_M = 0.40
SLEEVE_LENGTH_M = 0.005     # steel sleeve at the shaft's distal end
BLADE_LENGTH_M = 0.0102     # = kinematics.TIP_LENGTH

# Colours: a black shaft, steel (darker than 0.65 in value: the renderers' metal look), a darker grip insert.
SHAFT_BLACK = (0.12, 0.12, 0.14, 1.0)
STEEL = (0.58, 0.58, 0.62, 1.0)
DARK_STEEL = (0.42, 0.42, 0.46, 1.0)
GRIP = (0.25, 0.25, 0.28, 1.0)

MAX_SHAPES_PER_ARRAY = 16     # createVisualShapeArray segfaults with more
NEEDLE_VISUAL_SEGMENTS = 16   # PyBullet's most shapes in one visual array; 11° apart the arc reads smooth
NEEDLE_TAPER = 0.2            # the last 20 % of the arc narrows to the point


class Part(NamedTuple):
    """One primitive in its link's frame (real metres): ``kind`` "box" (size = full extents), "cylinder" or
    "capsule" (size = (radius, length), along ``axis``), "sphere" (size = (radius,))."""
    kind: str
    size: tuple
    position: tuple
    axis: str | tuple   # "x", "y", "z" or a quaternion (x, y, z, w) turning the part's z onto its axis
    colour: tuple


_AXIS_QUAT = {"z": (0.0, 0.0, 0.0, 1.0),
              "x": (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)),    # +90° about y: z → x
              "y": (-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))}   # −90° about x: z → y


def _box(lo, hi, colour) -> Part:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return Part("box", tuple(hi - lo), tuple((lo + hi) / 2), "z", colour)


def _cyl(radius, z0, z1, axis, colour, centre=(0.0, 0.0, 0.0)) -> Part:
    """A cylinder along ``axis`` from ``z0`` to ``z1`` on that axis, through ``centre``'s other coordinates."""
    pos = list(centre)
    pos["xyz".index(axis)] = (z0 + z1) / 2
    return Part("cylinder", (radius, z1 - z0), tuple(pos), axis, colour)


def roll_link_parts() -> list[Part]:
    """Link 3: the shaft, its steel sleeve and the proximal clevis holding the pitch pin (along y)."""
    r, end = SHAFT_RADIUS_M, 0.0025   # the shaft's end face sits 2.5 mm short of the pitch axis
    prong_in, prong_out = 0.0023, 0.0036
    return [
        _cyl(r, -SHAFT_LENGTH_M, -end - SLEEVE_LENGTH_M, "z", SHAFT_BLACK),
        _cyl(r, -end - SLEEVE_LENGTH_M, -end, "z", STEEL),
        _box((-0.0022, prong_in, -end - 0.0005), (0.0022, prong_out, 0.0022), STEEL),
        _box((-0.0022, -prong_out, -end - 0.0005), (0.0022, -prong_in, 0.0022), STEEL),
        _cyl(0.0008, -0.0040, 0.0040, "y", DARK_STEEL),   # the pitch pin, its ends showing on the prongs
    ]


def wrist_link_parts(wrist_length: float) -> list[Part]:
    """Link 4: hub round the pitch pin (z), the wrist body along x, the distal clevis holding the yaw pin (y)."""
    L = wrist_length
    prong_in, prong_out = 0.0014, 0.0023
    return [
        _cyl(0.0021, -0.0022, 0.0022, "z", STEEL),
        _box((0.0012, -0.0019, -0.0019), (L - 0.0030, 0.0019, 0.0019), STEEL),
        _box((L - 0.0034, prong_in, -0.0016), (L + 0.0016, prong_out, 0.0016), STEEL),
        _box((L - 0.0034, -prong_out, -0.0016), (L + 0.0016, -prong_in, 0.0016), STEEL),
        _cyl(0.0006, -0.0028, 0.0028, "y", DARK_STEEL, centre=(L, 0.0, 0.0)),
    ]


def blade_parts(sign: float) -> list[Part]:
    """Jaw ``sign`` (+1: the blade opening towards +x): heel round the yaw pin, a wide proximal half, a narrower
    distal half with a rounded end, and the grip insert on its inner face (x = 0 when closed)."""
    s = 1.0 if sign > 0 else -1.0

    def span(a, b):   # an x interval on the blade's side, from a to b mm off the closing plane
        return (min(s * a, s * b), max(s * a, s * b))

    x_heel, x_mid, x_tip = span(0.0, 0.0013), span(0.0002, 0.0014), span(0.0002, 0.0012)
    x_grip = span(0.0, 0.0002)
    return [
        _box((x_heel[0], -0.0012, -0.0012), (x_heel[1], 0.0020, 0.0012), STEEL),
        _box((x_mid[0], 0.0020, -0.0011), (x_mid[1], 0.0062, 0.0011), STEEL),
        _box((x_tip[0], 0.0062, -0.0008), (x_tip[1], BLADE_LENGTH_M - 0.0006, 0.0008), STEEL),
        _cyl(0.0006, x_tip[0], x_tip[1], "x", STEEL, centre=(0.0, BLADE_LENGTH_M - 0.0006, 0.0)),
        _box((x_grip[0], 0.0022, -0.0009), (x_grip[1], BLADE_LENGTH_M - 0.0008, 0.0009), GRIP),
    ]


def tool_link_parts(wrist_length: float) -> dict[int, list[Part]]:
    """The instrument's parts on the PSM's tool links (3 roll, 4 wrist pitch); the blades: :func:`blade_parts`."""
    return {3: roll_link_parts(), 4: wrist_link_parts(wrist_length)}


def needle_visual_parts(radius: float, wire_radius: float, colour) -> list[Part]:
    """The needle's arc from 90° to 270° (from +y through −x to −y, the needle frame of ``objects``), in short
    capsules tangent to the arc; the point (at 270°) tapers over the last ``NEEDLE_TAPER`` of the arc."""
    n = NEEDLE_VISUAL_SEGMENTS
    angles = np.linspace(np.pi / 2, 3 * np.pi / 2, n + 1)
    points = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1) * radius
    parts = []
    for k, (a, b) in enumerate(zip(points[:-1], points[1:])):
        along = (k + 0.5) / n
        taper = min(1.0, (1.0 - along) / NEEDLE_TAPER)
        r = wire_radius * max(0.25, taper)
        d = b - a
        yaw = math.atan2(d[1], d[0])
        # z onto the chord: 90° about y (z → x), then the chord's heading about z.
        quat = _quat_multiply((0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), _AXIS_QUAT["x"])
        parts.append(Part("capsule", (r, float(np.linalg.norm(d))), tuple((a + b) / 2), quat, colour))
    return parts


def _quat_multiply(q1, q2) -> tuple:
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)


def part_quaternion(part: Part) -> tuple:
    return _AXIS_QUAT[part.axis] if isinstance(part.axis, str) else tuple(part.axis)


_KINDS = {"box": pb.GEOM_BOX, "cylinder": pb.GEOM_CYLINDER, "capsule": pb.GEOM_CAPSULE, "sphere": pb.GEOM_SPHERE}


def visual_shape_array(client, parts: list[Part], scale: float) -> int:
    """One PyBullet visual shape (array) of ``parts``, built ``scale`` times larger than real."""
    if len(parts) > MAX_SHAPES_PER_ARRAY:   # PyBullet crashes the process beyond it
        raise ValueError(f"{len(parts)} parts in one visual shape; PyBullet takes at most {MAX_SHAPES_PER_ARRAY}")
    half, radii, lengths = [], [], []
    for p in parts:
        if p.kind == "box":
            half.append([v * scale / 2 for v in p.size])
            radii.append(0.0)
            lengths.append(0.0)
        else:
            half.append([0.0, 0.0, 0.0])
            radii.append(p.size[0] * scale)
            lengths.append(p.size[1] * scale if len(p.size) > 1 else 0.0)
    return client.createVisualShapeArray(
        [_KINDS[p.kind] for p in parts], halfExtents=half, radii=radii, lengths=lengths,
        rgbaColors=[list(p.colour) for p in parts],
        visualFramePositions=[[v * scale for v in p.position] for p in parts],
        visualFrameOrientations=[list(part_quaternion(p)) for p in parts])

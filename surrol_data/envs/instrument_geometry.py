"""What the instruments and the needle look like: one definition of their visual parts for every renderer.

The PSM carries a da Vinci EndoWrist-style needle driver, modelled here from primitives (no third-party meshes):

* the shaft, 8 mm across (the EndoWrist's diameter), black, with a steel sleeve at its distal end;
* the proximal clevis: two steel prongs at the end of the shaft holding the wrist-pitch pin;
* the wrist link (pitch axis → yaw axis, ``kinematics.WRIST_LENGTH``) with a hub round the pitch pin and the
  distal clevis holding the yaw pin;
* two jaw blades, 10.2 mm long (``kinematics.TIP_LENGTH``), each on its own jaw joint, so they open and close
  with ``jaw_angle``: a wide heel, a narrower distal half, and a darker grip insert on the inner face.

The needle is a smooth tube along its arc (:func:`needle_mesh`), tapering to its point over the last
``NEEDLE_TAPER`` of its length (the 6-capsule collision shape is unchanged). It is a mesh, not a chain of capsules:
TinyRenderer shades a primitive with normals pointing from the primitive's centre to each of its vertices, so
along a capsule much longer than it is thick the normals run along the wire, one end of every capsule lit and the
other dark — a striped needle. The mesh carries the tube's true normals; it is written to ``NEEDLE_MESH_FILE``
(an OBJ that :func:`needle_obj_text` makes, kept in the package) because PyBullet hands a mesh's triangles back to
the other renderers only as a file name.

The instrument's parts are meshed the same way, for the same reason: TinyRenderer's centre-based normals shade a
long shaft as if it were a ball (light or dark along its length, never round across it) and a flat blade face as a
gradient towards its corners. Each piece of the instrument (:data:`PIECES`: the shaft with its clevis, the wrist,
each jaw blade) is one OBJ per colour in ``MESH_DIR`` (:func:`instrument_obj_texts`, remade by
:func:`write_instrument_meshes`): the parts' triangles (:mod:`~surrol_data.envs.primitive_meshes`, the meshes the
renderers draw for primitives) placed in the link's frame, with flat normals on flat faces and round ones on round
faces.

These meshes become the PyBullet *visual* shapes of the bodies (:func:`instrument_visual_shape`), so TinyRenderer
draws them, and the Panda3D mirror and the Rerun meshes read them back from PyBullet — one geometry for the three.
Collision shapes are built elsewhere (``psm.py``, ``objects.py``) and do not depend on this module: the physics
is the same whatever the instruments look like.

Frames (the PSM's link frames, :mod:`surrol_data.envs.psm`): tool roll (link 3): origin on the wrist-pitch axis,
z along the shaft towards the tip, pitch axis = y. Wrist pitch (link 4): z = pitch axis, x along the wrist to
the yaw axis. Jaws (links 6, 7): origin on the yaw axis (z), blades along +y, blade ``s`` opening towards s·x.
Sizes in real metres; :func:`instrument_visual_shape` scales them to the scene.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from surrol_data.envs import kinematics as kin
from surrol_data.envs import primitive_meshes
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

COLOUR_NAMES = {SHAFT_BLACK: "black", STEEL: "steel", DARK_STEEL: "dark_steel", GRIP: "grip"}   # in file names

MAX_SHAPES_PER_ARRAY = 16     # createVisualShapeArray segfaults with more
NEEDLE_TAPER = 0.2            # the last 20 % of the arc narrows to the point
NEEDLE_POINT = 0.5            # the point keeps this share of the wire's radius (a finer one drops out of TinyRenderer)
NEEDLE_RINGS = 72             # cross-sections along the arc: 2.5° apart, the silhouette reads smooth
NEEDLE_SIDES = 10             # vertices round the wire
MESH_DIR = Path(__file__).with_name("meshes")
NEEDLE_MESH_FILE = MESH_DIR / "needle.obj"


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


# The instrument's pieces, each drawn on one link of the PSM (psm.py: link 3 tool roll, 4 wrist pitch, 6 and 7 the
# jaw blades opening towards +x and −x).
PIECES = ("shaft", "wrist", "jaw_plus", "jaw_minus")


def piece_parts(piece: str) -> list[Part]:
    """The parts of one of :data:`PIECES`, in its link's frame."""
    if piece == "shaft":
        return roll_link_parts()
    if piece == "wrist":
        return wrist_link_parts(kin.WRIST_LENGTH)
    if piece in ("jaw_plus", "jaw_minus"):
        return blade_parts(+1.0 if piece == "jaw_plus" else -1.0)
    raise ValueError(f"unknown instrument piece {piece!r}; the pieces are {', '.join(PIECES)}")


def part_mesh(part: Part) -> primitive_meshes.Mesh:
    """The part's surface in its link's frame (real metres)."""
    if part.kind == "box":
        mesh = primitive_meshes.box(part.size)
    elif part.kind == "cylinder":
        mesh = primitive_meshes.cylinder(part.size[1], part.size[0])
    elif part.kind == "capsule":
        mesh = primitive_meshes.capsule(part.size[1], part.size[0])
    elif part.kind == "sphere":
        mesh = primitive_meshes.sphere(part.size[0])
    else:
        raise ValueError(f"unknown part kind {part.kind!r}; use box, cylinder, capsule or sphere")
    rot = np.array(pb.getMatrixFromQuaternion(part_quaternion(part))).reshape(3, 3)
    return primitive_meshes.Mesh(mesh.positions @ rot.T + np.asarray(part.position), mesh.normals @ rot.T,
                                 mesh.uvs, mesh.triangles)


def _colours(parts: list[Part]) -> list[tuple]:
    """The parts' colours, each once, in the parts' order."""
    return list(dict.fromkeys(p.colour for p in parts))


def piece_mesh_files(piece: str) -> list[tuple[Path, tuple]]:
    """(OBJ file, colour) of each colour of ``piece``: the files :func:`instrument_visual_shape` builds it from."""
    return [(MESH_DIR / f"{piece}_{COLOUR_NAMES[colour]}.obj", colour) for colour in _colours(piece_parts(piece))]


def instrument_obj_texts() -> dict[Path, str]:
    """Every instrument mesh file's OBJ text: per piece and colour, the parts of that colour merged."""
    texts = {}
    for piece in PIECES:
        parts = piece_parts(piece)
        for path, colour in piece_mesh_files(piece):
            mesh = primitive_meshes.merge(*[part_mesh(p) for p in parts if p.colour == colour])
            texts[path] = obj_text(f"the instrument's {piece} ({COLOUR_NAMES[colour]} parts): "
                                   "surrol_data.envs.instrument_geometry.instrument_obj_texts(); remade by "
                                   "write_instrument_meshes(), do not edit",
                                   mesh.positions, mesh.normals, mesh.triangles)
    return texts


def write_instrument_meshes() -> list[Path]:
    """Remake the instrument's OBJ files in ``MESH_DIR`` after changing a part, a size or a colour here."""
    MESH_DIR.mkdir(exist_ok=True)
    texts = instrument_obj_texts()
    for path, text in texts.items():
        path.write_text(text)
    return list(texts)


def instrument_visual_shape(client, piece: str, scale: float) -> int:
    """The PyBullet visual shape of one of :data:`PIECES`: its mesh files, built ``scale`` times larger than real."""
    files = piece_mesh_files(piece)
    if len(files) > MAX_SHAPES_PER_ARRAY:   # PyBullet crashes the process beyond it
        raise ValueError(f"{len(files)} meshes in one visual shape; PyBullet takes at most {MAX_SHAPES_PER_ARRAY}")
    missing = [str(path) for path, _ in files if not path.is_file()]
    if missing:
        raise FileNotFoundError(f"instrument mesh {missing[0]} is missing: remake the meshes with "
                                "surrol_data.envs.instrument_geometry.write_instrument_meshes()")
    n = len(files)
    return client.createVisualShapeArray(
        [pb.GEOM_MESH] * n, fileNames=[str(path) for path, _ in files], meshScales=[[scale] * 3] * n,
        rgbaColors=[list(colour) for _, colour in files],
        visualFramePositions=[[0.0, 0.0, 0.0]] * n, visualFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n)


def needle_mesh(radius: float, wire_radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The needle's surface in its frame (metres): a tube of ``wire_radius`` along the arc of ``radius`` from 90°
    to 270° (from +y through −x to −y, the needle frame of ``objects``), closed at both ends, the point (270°)
    tapered. Returns positions (N, 3), unit outward normals (N, 3) and triangles (M, 3), counter-clockwise seen
    from outside."""
    k = np.arange(NEEDLE_RINGS + 1)
    along = k / NEEDLE_RINGS
    angle = np.pi / 2 + np.pi * along
    radial = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)      # out of the arc
    tangent = np.stack([-np.sin(angle), np.cos(angle), np.zeros_like(angle)], axis=1)    # towards the point
    wire = wire_radius * np.clip((1.0 - along) / NEEDLE_TAPER, NEEDLE_POINT, 1.0)
    phi = 2 * np.pi * np.arange(NEEDLE_SIDES) / NEEDLE_SIDES
    # Ring k, side j: round the wire in the plane of the radial and the needle's normal (z).
    around = (np.cos(phi)[None, :, None] * radial[:, None, :]
              + np.sin(phi)[None, :, None] * np.array([0.0, 0.0, 1.0]))
    centres = radial * radius
    positions = (centres[:, None, :] + wire[:, None, None] * around).reshape(-1, 3)
    normals = around.reshape(-1, 3)
    index = np.arange(positions.shape[0]).reshape(NEEDLE_RINGS + 1, NEEDLE_SIDES)
    a, b = index[:-1], np.roll(index[:-1], -1, axis=1)
    c, d = np.roll(index[1:], -1, axis=1), index[1:]
    triangles = [np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)]
    # Rounded-off ends: a pole half a wire radius beyond each end ring, its normal along the wire.
    points, directions = [positions], [normals]
    for ring, sign in ((0, -1.0), (NEEDLE_RINGS, 1.0)):
        pole = positions.shape[0] + len(points) - 1
        points.append((centres[ring] + sign * 0.5 * wire[ring] * tangent[ring])[None])
        directions.append((sign * tangent[ring])[None])
        rim = index[ring]
        fan = np.stack([np.full(NEEDLE_SIDES, pole), np.roll(rim, -1), rim], -1)
        triangles.append(fan if sign > 0 else fan[:, ::-1])
    return np.concatenate(points), np.concatenate(directions), np.concatenate(triangles)


def obj_text(header: str, positions, normals, triangles) -> str:
    """Wavefront OBJ text of a mesh (a normal per vertex, sharing its index, as PyBullet and
    :func:`surrol_data.render.body_shapes.obj_mesh` read it), under a ``# header`` comment line."""
    lines = [f"# {header}"]
    lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in positions]
    lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals]
    lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in np.asarray(triangles) + 1]
    return "\n".join(lines) + "\n"


def needle_obj_text(radius: float, wire_radius: float) -> str:
    """:func:`needle_mesh` as Wavefront OBJ text."""
    return obj_text(f"the needle's visual surface: surrol_data.envs.instrument_geometry.needle_obj_text({radius}, "
                    f"{wire_radius}); remade by write_needle_mesh(radius, wire_radius), do not edit",
                    *needle_mesh(radius, wire_radius))


def write_needle_mesh(radius: float, wire_radius: float) -> Path:
    """Remake ``NEEDLE_MESH_FILE`` after changing the needle's sizes (``objects.NEEDLE_RADIUS``,
    ``objects.NEEDLE_WIRE_RADIUS``, which ``objects`` passes here) or this module."""
    MESH_DIR.mkdir(exist_ok=True)
    NEEDLE_MESH_FILE.write_text(needle_obj_text(radius, wire_radius))
    return NEEDLE_MESH_FILE


def needle_visual_shape(client, scale: float, colour) -> int:
    """The needle's PyBullet visual shape: ``NEEDLE_MESH_FILE`` (real metres) built ``scale`` times larger."""
    return client.createVisualShape(pb.GEOM_MESH, fileName=str(NEEDLE_MESH_FILE), meshScale=[scale] * 3,
                                    rgbaColor=list(colour))


def part_quaternion(part: Part) -> tuple:
    return _AXIS_QUAT[part.axis] if isinstance(part.axis, str) else tuple(part.axis)

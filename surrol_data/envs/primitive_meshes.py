"""Triangle meshes (positions, normals, texture coordinates) of PyBullet's primitive shapes: what the renderers
draw for a primitive visual shape, and what the instruments' visual meshes are made of
(:mod:`~surrol_data.envs.instrument_geometry`).

PyBullet's conventions, which the meshes follow: a box is given by its full extents and centred on its
frame; cylinders and capsules lie along their frame's z axis, ``length`` being the straight part (a capsule
adds a hemisphere of ``radius`` at each end); a sphere is centred on its frame.
"""

from __future__ import annotations

import numpy as np

# Facets around a circle: smooth at 640×480 for the sizes of the scene (a few cm across) and cheap.
CIRCLE_SEGMENTS = 32
SPHERE_RINGS = 16


class Mesh:
    """Vertex arrays (N, 3) positions, (N, 3) unit normals, (N, 2) texture coordinates and (M, 3) triangles."""

    def __init__(self, positions, normals, uvs, triangles):
        self.positions = np.asarray(positions, np.float32)
        self.normals = np.asarray(normals, np.float32)
        self.uvs = np.asarray(uvs, np.float32)
        self.triangles = np.asarray(triangles, np.int32)


def box(extents) -> Mesh:
    """A box of full ``extents`` (x, y, z); texture coordinates in metres of the face (for tiled textures)."""
    half = np.asarray(extents, np.float64) / 2
    positions, normals, uvs, triangles = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_axis, v_axis = [a for a in range(3) if a != axis]
            if np.cross(np.eye(3)[u_axis], np.eye(3)[v_axis])[axis] * sign < 0:
                u_axis, v_axis = v_axis, u_axis   # counter-clockwise seen from outside: front faces
            base = len(positions)
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis] = sign * half[axis]
                p[u_axis] = du * half[u_axis]
                p[v_axis] = dv * half[v_axis]
                n = np.zeros(3)
                n[axis] = sign
                positions.append(p)
                normals.append(n)
                uvs.append((p[u_axis], p[v_axis]))
            triangles += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return Mesh(positions, normals, uvs, triangles)


def _lathe(profile: list[tuple[float, float, float, float]], segments: int = CIRCLE_SEGMENTS) -> Mesh:
    """Surface of revolution about z from a profile of (radius, z, normal_r, normal_z) rows, bottom to top."""
    positions, normals, uvs, triangles = [], [], [], []
    angles = np.linspace(0.0, 2 * np.pi, segments + 1)
    for i, (r, z, nr, nz) in enumerate(profile):
        for j, a in enumerate(angles):
            c, s = np.cos(a), np.sin(a)
            positions.append((r * c, r * s, z))
            normals.append((nr * c, nr * s, nz))
            uvs.append((j / segments, i / max(1, len(profile) - 1)))
    ring = segments + 1
    for i in range(len(profile) - 1):
        for j in range(segments):
            a, b = i * ring + j, i * ring + j + 1
            c, d = a + ring, b + ring
            triangles += [(a, b, d), (a, d, c)]
    return Mesh(positions, normals, uvs, triangles)


def _disc(radius: float, z: float, up: bool, segments: int = CIRCLE_SEGMENTS) -> Mesh:
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    positions = [(0.0, 0.0, z)] + [(radius * np.cos(a), radius * np.sin(a), z) for a in angles]
    normals = [(0.0, 0.0, 1.0 if up else -1.0)] * (segments + 1)
    uvs = [(0.5, 0.5)] + [(0.5 + 0.5 * np.cos(a), 0.5 + 0.5 * np.sin(a)) for a in angles]
    triangles = [(0, 1 + j, 1 + (j + 1) % segments) if up else (0, 1 + (j + 1) % segments, 1 + j)
                 for j in range(segments)]
    return Mesh(positions, normals, uvs, triangles)


def merge(*meshes: Mesh) -> Mesh:
    offset, triangles = 0, []
    for m in meshes:
        triangles.append(m.triangles + offset)
        offset += len(m.positions)
    return Mesh(np.concatenate([m.positions for m in meshes]), np.concatenate([m.normals for m in meshes]),
                np.concatenate([m.uvs for m in meshes]), np.concatenate(triangles))


def cylinder(length: float, radius: float) -> Mesh:
    h = length / 2
    side = _lathe([(radius, -h, 1.0, 0.0), (radius, h, 1.0, 0.0)])
    return merge(side, _disc(radius, -h, up=False), _disc(radius, h, up=True))


def _hemisphere_profile(radius: float, z0: float, top: bool) -> list[tuple[float, float, float, float]]:
    rows = []
    for k in range(SPHERE_RINGS // 2 + 1):
        # polar angle from the pole: 0 at the pole, π/2 at the equator
        theta = (np.pi / 2) * (k / (SPHERE_RINGS // 2))
        nr, nz = np.sin(theta), np.cos(theta) if top else -np.cos(theta)
        rows.append((radius * nr, z0 + radius * nz, nr, nz))
    return rows if not top else rows[::-1]


def capsule(length: float, radius: float) -> Mesh:
    h = length / 2
    bottom = _hemisphere_profile(radius, -h, top=False)
    top = _hemisphere_profile(radius, h, top=True)
    return _lathe(bottom + top)


def sphere(radius: float) -> Mesh:
    return _lathe(_hemisphere_profile(radius, 0.0, top=False) + _hemisphere_profile(radius, 0.0, top=True)[1:])

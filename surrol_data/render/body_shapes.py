"""What a PyBullet body looks like, read back from PyBullet without Panda3D: its visual shapes (primitives and OBJ
meshes) as triangle meshes and where each of its links is. The Panda3D mirror (:mod:`~surrol_data.render.scene_mirror`)
and the Rerun scene (:mod:`surrol_data.viz.scene_meshes`) both build on it, so they draw the same geometry.
"""

from __future__ import annotations

import functools

import numpy as np

from surrol_data.envs.physics import pb  # physics imports pybullet quietly
from surrol_data.envs import primitive_meshes

PRIMITIVE_KINDS = {pb.GEOM_BOX, pb.GEOM_SPHERE, pb.GEOM_CYLINDER, pb.GEOM_CAPSULE}


def primitive_mesh(kind: int, dims) -> primitive_meshes.Mesh:
    """The mesh of a primitive visual shape from ``getVisualShapeData``'s kind and dimensions (scene units)."""
    if kind == pb.GEOM_BOX:
        return primitive_meshes.box(dims)
    if kind == pb.GEOM_SPHERE:
        return primitive_meshes.sphere(dims[0])
    if kind == pb.GEOM_CYLINDER:
        return primitive_meshes.cylinder(dims[0], dims[1])
    if kind == pb.GEOM_CAPSULE:
        return primitive_meshes.capsule(dims[0], dims[1])
    raise ValueError(f"PyBullet geometry type {kind} is not a primitive (box, sphere, cylinder, capsule)")


def visual_mesh(kind: int, dims, filename) -> primitive_meshes.Mesh | None:
    """The mesh of a visual shape from ``getVisualShapeData``'s kind, dimensions and file name (scene units):
    a primitive, or a Wavefront OBJ file scaled by its mesh scale (``dims``); None for what PyBullet does not hand
    back (a mesh given as vertices has no file) or for other mesh formats."""
    if kind in PRIMITIVE_KINDS:
        return primitive_mesh(kind, dims)
    path = filename.decode() if isinstance(filename, bytes) else str(filename)
    if kind != pb.GEOM_MESH or not path.lower().endswith(".obj"):
        return None
    mesh = obj_mesh(path)
    return primitive_meshes.Mesh(mesh.positions * np.asarray(dims, np.float32), mesh.normals, mesh.uvs, mesh.triangles)


@functools.cache
def obj_mesh(path: str) -> primitive_meshes.Mesh:
    """A triangulated OBJ file with one normal per vertex at the vertex's index (``f a//a b//b c//c``, as
    :func:`surrol_data.envs.instrument_geometry.needle_obj_text` writes them)."""
    positions, normals, triangles = [], [], []
    with open(path, encoding="utf-8") as f:
        for line in f:
            kind, _, rest = line.partition(" ")
            if kind == "v":
                positions.append([float(v) for v in rest.split()[:3]])
            elif kind == "vn":
                normals.append([float(v) for v in rest.split()[:3]])
            elif kind == "f":
                triangles.append([int(v.split("/")[0]) - 1 for v in rest.split()[:3]])
    if len(normals) != len(positions):
        raise ValueError(f"{path}: {len(positions)} vertices but {len(normals)} normals (one per vertex expected)")
    return primitive_meshes.Mesh(positions, normals, np.zeros((len(positions), 2)), triangles)


def base_inertial_frame(client, body: int):
    """The base's inertial frame in its link frame: the base's visual frames are relative to its link frame,
    while ``getBasePositionAndOrientation`` reports the inertial frame.

    Static maximal-coordinate bodies have no inertial frame of their own, and PyBullet then reports
    uninitialised memory (seen: a 180° turn with a denormal component); such a frame is the identity."""
    pos, orn = client.getDynamicsInfo(body, -1)[3:5]
    values = np.abs(np.array([*pos, *orn]))
    garbage = np.any((values > 0) & (values < 1e-200)) or not np.isfinite(values).all() \
        or abs(float(np.dot(orn, orn)) - 1.0) > 1e-6
    return ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)) if garbage else (pos, orn)


def link_world_poses(client, body: int, links, inertial_from_link, forward_kinematics: bool = True) -> dict[int, tuple]:
    """(position, quaternion xyzw) in scene units of each link of ``links`` (-1: the base's link frame).

    ``forward_kinematics=False``: each link where the last physics step left its stored frame (where that step
    began, one physics step old) instead of PyBullet's forward-kinematics pass, which moves the solver's next results
    in their last bits (growing to millimetres over an episode): for views drawn while an episode runs that must
    leave it as it is."""
    poses = {}
    if -1 in links:
        pos, orn = client.getBasePositionAndOrientation(body)
        poses[-1] = client.multiplyTransforms(pos, orn, *inertial_from_link)
    moving = [link for link in links if link >= 0]
    if moving:
        for link, state in zip(moving, client.getLinkStates(body, moving, computeForwardKinematics=forward_kinematics)):
            poses[link] = (state[4], state[5])
    return poses

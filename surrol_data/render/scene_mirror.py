"""A Panda3D copy of a PyBullet scene: one node per body and link, built from the scene's visual shapes.

Everything is read from PyBullet (``getVisualShapeData``, ``getBasePositionAndOrientation``,
``getLinkStates``), never from task code, so any scene — including tasks added later — is mirrored. Bodies
that appear (respawned objects) get nodes on the next :meth:`SceneMirror.sync`; bodies that are gone lose
theirs. Nodes live under a root scaled by ``1 / scene_scale`` so that the Panda3D scene is in real metres
(light falloff and shadow bias are physical quantities).

Each body's node carries the tag ``SEGMENTATION_TAG`` = its PyBullet unique id, which the segmentation
pass turns into a flat id colour.
"""

from __future__ import annotations

import numpy as np
from panda3d.core import (
    Geom,
    GeomNode,
    GeomTriangles,
    GeomVertexData,
    GeomVertexFormat,
    LQuaternionf,
    LVecBase3f,
    Material,
    NodePath,
    SamplerState,
    Texture,
    TextureStage,
    TransformState,
    TransparencyAttrib,
)

from surrol_data.envs.physics import pb  # physics imports pybullet quietly
from surrol_data.envs import primitive_meshes
from surrol_data.render import body_shapes, materials
from surrol_data.render.endoscope_light import NO_SHADOW, SHADOW_TAG

SEGMENTATION_TAG = "pybullet_body"
_MESH_KINDS = {pb.GEOM_BOX, pb.GEOM_SPHERE, pb.GEOM_CYLINDER, pb.GEOM_CAPSULE, pb.GEOM_MESH}


def _quat(q) -> LQuaternionf:
    x, y, z, w = q   # PyBullet (x, y, z, w); Panda3D (w, x, y, z)
    return LQuaternionf(w, x, y, z)


def _transform(position, orientation) -> TransformState:
    return TransformState.make_pos_quat_scale(LVecBase3f(*position), _quat(orientation), LVecBase3f(1, 1, 1))


def _geom_node(name: str, mesh: primitive_meshes.Mesh) -> GeomNode:
    data = GeomVertexData(name, GeomVertexFormat.get_v3n3t2(), Geom.UH_static)
    data.unclean_set_num_rows(len(mesh.positions))
    interleaved = np.concatenate([mesh.positions, mesh.normals, mesh.uvs], axis=1).astype(np.float32)
    memoryview(data.modify_array(0)).cast("B")[:] = interleaved.tobytes()
    prim = GeomTriangles(Geom.UH_static)
    prim.set_index_type(Geom.NT_uint32)
    handle = prim.modify_vertices()
    handle.unclean_set_num_rows(mesh.triangles.size)
    memoryview(handle).cast("B")[:] = mesh.triangles.astype(np.uint32).tobytes()
    geom = Geom(data)
    geom.add_primitive(prim)
    node = GeomNode(name)
    node.add_geom(geom)
    return node


class SceneMirror:
    """Mirrors the bodies of PyBullet ``client`` under ``parent`` (call :meth:`sync` before each frame)."""

    def __init__(self, client, parent: NodePath, scene_scale: float = 1.0):
        self.client = client
        self.scene_scale = float(scene_scale)
        self.root = parent.attach_new_node("pybullet_scene")
        self.root.set_scale(1.0 / self.scene_scale)
        # body id -> (its visual shape data, its node, link index -> link node, base link-from-inertial pose)
        self._bodies: dict[int, tuple] = {}
        self._textures: dict[str, Texture] = {}
        self._meshes: dict[tuple, tuple[GeomNode, primitive_meshes.Mesh] | None] = {}   # None: not a mesh we can read

    @property
    def body_ids(self) -> list[int]:
        return list(self._bodies)

    def sync(self, forward_kinematics: bool = True) -> None:
        """Add nodes for new bodies, drop those of removed ones, and copy every link's world pose
        (``forward_kinematics``: see :func:`~surrol_data.render.body_shapes.link_world_poses`)."""
        c = self.client
        present = {c.getBodyUniqueId(i) for i in range(c.getNumBodies())}
        for body in list(self._bodies):
            if body not in present:
                self._bodies.pop(body)[1].remove_node()
        for body in present:
            shapes_now = tuple(c.getVisualShapeData(body))
            known = self._bodies.get(body)
            if known is None or known[0] != shapes_now:   # new body, or an id reused by another one
                if known is not None:
                    known[1].remove_node()
                inertial_from_link = c.invertTransform(*body_shapes.base_inertial_frame(c, body))
                self._bodies[body] = (shapes_now, *self._build_body(body, shapes_now), inertial_from_link)
            self._place(body, forward_kinematics)

    # ------------------------------------------------------------------ building
    def _build_body(self, body: int, visuals: tuple) -> tuple[NodePath, dict[int, NodePath]]:
        node = self.root.attach_new_node(f"body{body}")
        node.set_tag(SEGMENTATION_TAG, str(body))
        if visuals and all(float(shape[7][3]) < 0.999 for shape in visuals):
            # A translucent body is a cue drawn for the eye (the goal marker), not a thing in the cavity: a shadow
            # of it would show something that is not there.
            node.set_tag(SHADOW_TAG, NO_SHADOW)
        links: dict[int, NodePath] = {}
        for shape in visuals:
            link, kind, dims, filename = shape[1], shape[2], shape[3], shape[4]
            local_pos, local_orn, rgba = shape[5], shape[6], shape[7]
            if kind not in _MESH_KINDS:
                continue
            if link not in links:
                links[link] = node.attach_new_node(f"link{link}")
            geom = self._shape_node(kind, dims, filename, rgba)
            if geom is None:
                continue
            geom.reparent_to(links[link])
            geom.set_transform(_transform(local_pos, local_orn))
        return node, links

    def _shape_node(self, kind: int, dims, filename: bytes, rgba) -> NodePath | None:
        s = self.scene_scale
        radius_m = None
        key = (kind, tuple(round(float(v), 7) for v in dims), filename)
        if key not in self._meshes:
            mesh = body_shapes.visual_mesh(kind, dims, filename)
            self._meshes[key] = None if mesh is None else (_geom_node(f"shape{kind}", mesh), mesh)
        if self._meshes[key] is not None:
            geom, mesh = self._meshes[key]
            np_ = NodePath(geom.make_copy())
            if kind in (pb.GEOM_SPHERE,):
                radius_m = dims[0] / s
            elif kind in (pb.GEOM_CYLINDER, pb.GEOM_CAPSULE):
                radius_m = dims[1] / s
            elif kind == pb.GEOM_MESH:   # a mesh is as thin as its thinnest extent (the needle: its wire)
                radius_m = float(np.ptp(mesh.positions, axis=0).min()) / 2 / s
        else:
            path = filename.decode() if isinstance(filename, bytes) else str(filename)
            if kind != pb.GEOM_MESH or not path:
                return None   # a mesh from vertices: PyBullet does not hand its triangles back
            from panda3d.core import Filename, Loader

            model = Loader.get_global_ptr().load_sync(Filename.from_os_specific(path))
            if model is None:
                return None
            np_ = NodePath(model)
            np_.set_scale(*dims)
        self._apply_look(np_, kind, radius_m, rgba)
        return np_

    def _apply_look(self, node: NodePath, kind: int, radius_m, rgba) -> None:
        look = materials.look_for(kind, radius_m, rgba)
        r, g, b, a = (float(v) for v in rgba)
        mat = Material(look.name)
        mat.set_diffuse((r, g, b, a))
        mat.set_ambient((r, g, b, a))
        mat.set_specular((look.specular, look.specular, look.specular, 1.0))
        mat.set_shininess(look.shininess)
        node.set_material(mat, 1)
        node.set_color(r, g, b, a)
        if a < 0.999:
            node.set_transparency(TransparencyAttrib.M_alpha)
        if look.texture is not None:
            tile_m = materials.TISSUE_TILE_M if look.texture == "tissue" else materials.SILICONE_TILE_M
            node.set_texture(self._texture(look.texture, look.texture_strength))
            # Texture coordinates are in scene units: one tile per ``tile_m`` real metres.
            node.set_tex_scale(TextureStage.get_default(), 1.0 / (tile_m * self.scene_scale))

    def _texture(self, kind: str, strength: float) -> Texture:
        if kind not in self._textures:
            pixels = 1.0 - strength * (1.0 - materials.texture_pixels(kind))
            grey = np.round(pixels * 255).astype(np.uint8)
            tex = Texture(kind)
            tex.setup_2d_texture(grey.shape[1], grey.shape[0], Texture.T_unsigned_byte, Texture.F_luminance)
            tex.set_ram_image(np.ascontiguousarray(grey[::-1]).tobytes())
            tex.set_wrap_u(SamplerState.WM_repeat)
            tex.set_wrap_v(SamplerState.WM_repeat)
            tex.set_minfilter(SamplerState.FT_linear_mipmap_linear)
            tex.set_magfilter(SamplerState.FT_linear)
            self._textures[kind] = tex
        return self._textures[kind]

    # ------------------------------------------------------------------ poses
    def _place(self, body: int, forward_kinematics: bool) -> None:
        _, node, links, inertial_from_link = self._bodies[body]
        poses = body_shapes.link_world_poses(self.client, body, links, inertial_from_link, forward_kinematics)
        for link, pose in poses.items():
            links[link].set_transform(_transform(*pose))

"""What the endoscope sees in Panda3D: the mirrored PyBullet scene, its light, and per-pixel shading.

One stage serves any number of cameras (the offscreen observation camera, the GUI's window): call
:meth:`EndoscopeStage.update` with the endoscope pose before drawing, then :meth:`place_camera`.
"""

from __future__ import annotations

import math

from panda3d.core import AntialiasAttrib, FrameBufferProperties, NodePath, PerspectiveLens, Point3, Vec3

from surrol_data.envs.camera import FAR_M, FOV_DEG, NEAR_M, TAN_HALF_FOV, camera_axes
from surrol_data.render.endoscope_light import MAX_EXPOSURE_DISTANCE_M, SHADOW_MAP_SIZE, EndoscopeLight
from surrol_data.render.phong_shader import phong_shader
from surrol_data.render.scene_mirror import SceneMirror


def endoscope_lens(width: int, height: int) -> PerspectiveLens:
    """The endoscope's lens: the same vertical field of view and clip range as TinyRenderer's camera."""
    lens = PerspectiveLens()
    aspect = width / height
    lens.set_fov(math.degrees(2 * math.atan(TAN_HALF_FOV * aspect)), FOV_DEG)
    lens.set_near_far(NEAR_M, FAR_M)
    return lens


def view_framebuffer(multisamples: int) -> FrameBufferProperties:
    """The frame buffer of a view of the scene: 8-bit RGBA, 24-bit depth, ``multisamples``× anti-aliasing."""
    fbp = FrameBufferProperties()
    fbp.set_rgb_color(True)
    fbp.set_rgba_bits(8, 8, 8, 8)
    fbp.set_depth_bits(24)
    fbp.set_multisamples(multisamples)
    return fbp


class EndoscopeStage:
    """The scene graph of one PyBullet scene (``scene_scale``: how much larger than real it is built)."""

    def __init__(self, client, scene_scale: float = 1.0, shadows: bool = True,
                 shadow_map_size: int = SHADOW_MAP_SIZE):
        self.root = NodePath("endoscope_stage")
        # Per-pixel Phong lighting, shadow map and texture modulation (see phong_shader for why not the
        # auto shader).
        self.root.set_shader(phong_shader())
        self.root.set_antialias(AntialiasAttrib.M_multisample)
        self.root.set_shader_input("u_shadows", 1.0 if shadows else 0.0)
        self.mirror = SceneMirror(client, self.root, scene_scale)
        self.light = EndoscopeLight(self.root, shadows=shadows, shadow_map_size=shadow_map_size)
        self._pose = None

    def update(self, world_T_eef, forward_kinematics: bool = True) -> None:
        """Copy the PyBullet poses and move the light to the endoscope at ``world_T_eef`` (4×4, real metres);
        ``forward_kinematics``: see :func:`~surrol_data.render.body_shapes.link_world_poses`."""
        self.mirror.sync(forward_kinematics)
        axes = camera_axes(world_T_eef)
        up = tuple(-v for v in axes.down)
        self._pose = (axes.eye, axes.forward, up)
        self.light.follow(axes.eye, axes.forward, up, self._axis_distance(axes))

    def _axis_distance(self, axes) -> float | None:
        """Real metres from the lens to the first surface on the optical axis (None: nothing there)."""
        s, reach = self.mirror.scene_scale, MAX_EXPOSURE_DISTANCE_M
        start = [e * s for e in axes.eye]
        end = [(e + reach * f) * s for e, f in zip(axes.eye, axes.forward)]
        hit = self.mirror.client.rayTest(start, end)[0]
        return None if hit[0] < 0 else hit[2] * reach

    def close(self) -> None:
        """Drop the scene graph and the light's shadow buffer (which otherwise goes on being drawn)."""
        self.light.close()
        self.root.remove_node()

    def place_camera(self, camera: NodePath) -> None:
        """Put ``camera`` at the endoscope pose of the last :meth:`update`."""
        eye, forward, up = self._pose
        camera.set_pos(*eye)
        camera.look_at(Point3(eye[0] + forward[0], eye[1] + forward[1], eye[2] + forward[2]), Vec3(*up))

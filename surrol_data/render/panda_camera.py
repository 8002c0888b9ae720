"""The endoscope camera rendered by Panda3D offscreen: RGB, depth and segmentation like TinyRenderer's.

Drop-in for :class:`surrol_data.envs.camera.EndoscopeCamera` (same constructor arguments and ``render``),
chosen with ``camera_renderer="panda3d"``. Two offscreen buffers share one stage:

* colour: per-pixel Phong shading under the endoscope light with shadow maps, ``multisamples``× MSAA;
* ids: no lighting, no anti-aliasing, each body drawn in a flat colour that encodes its PyBullet unique id
  (so segmentation ids equal TinyRenderer's), with the depth buffer read back for the depth image.
  It is drawn only when depth or segmentation is asked for.
"""

from __future__ import annotations

import numpy as np
from panda3d.core import (
    AntialiasAttrib,
    Camera,
    ColorAttrib,
    GraphicsEngine,
    GraphicsOutput,
    GraphicsPipe,
    LightAttrib,
    MaterialAttrib,
    NodePath,
    RenderState,
    ShaderAttrib,
    Texture,
    TextureAttrib,
    TransparencyAttrib,
    WindowProperties,
)

from surrol_data.envs.camera import FAR_M, NEAR_M, CameraImage, _checked_size
from surrol_data.render.display import RendererUnavailable, offscreen_pipe
from surrol_data.render.scene_mirror import SEGMENTATION_TAG
from surrol_data.render.stage import EndoscopeStage, endoscope_lens, view_framebuffer

_OVERRIDE = 1000   # beats every state the mirror sets on its nodes
BACKGROUND = (0.0, 0.0, 0.0)   # the cavity beyond the light's reach is dark


def _encode(body: int) -> tuple[float, float, float, float]:
    code = body + 1   # 0 stays the background
    return ((code & 255) / 255.0, ((code >> 8) & 255) / 255.0, ((code >> 16) & 255) / 255.0, 1.0)


class PandaEndoscopeCamera:
    """Renders the endoscope's view of PyBullet ``client`` with Panda3D (see the module docstring)."""

    def __init__(self, client, size: tuple[int, int] = (128, 128), scene_scale: float = 1.0,
                 shadows: bool = True, multisamples: int = 4, shadow_map_size: int | None = None):
        width, height = _checked_size(size)
        self.client = client
        self.width, self.height = width, height
        self.scene_scale = float(scene_scale)
        # The light's cone is wider than the view: about two shadow-map texels per image pixel across (by default).
        shadow_map = shadow_map_size or min(1024, max(256, 1 << (2 * max(width, height) - 1).bit_length()))
        self.stage = EndoscopeStage(client, scene_scale, shadows=shadows, shadow_map_size=shadow_map)
        pipe = offscreen_pipe()
        self.engine = GraphicsEngine(pipe)
        self._color_tex = Texture("endoscope_rgb")
        self._colour = self._buffer(pipe, "endoscope_rgb", multisamples, self._color_tex, None)
        self._colour_cam = self._camera(self._colour, "endoscope")
        self._id_tex, self._depth_tex = Texture("endoscope_ids"), Texture("endoscope_depth")
        self._depth_tex.set_format(Texture.F_depth_component32)
        self._depth_tex.set_component_type(Texture.T_float)
        self._ids = self._buffer(pipe, "endoscope_ids", 0, self._id_tex, self._depth_tex, host=self._colour)
        self._ids_cam = self._camera(self._ids, "endoscope_ids")
        self._ids.set_clear_color((0.0, 0.0, 0.0, 1.0))
        cam_node = self._ids_cam.node()
        flat = RenderState.make(LightAttrib.make_all_off(), ShaderAttrib.make_off(), TextureAttrib.make_all_off(),
                                MaterialAttrib.make_off(), _OVERRIDE)
        flat = flat.compose(RenderState.make(TransparencyAttrib.make(TransparencyAttrib.M_none),
                                             AntialiasAttrib.make(AntialiasAttrib.M_off), _OVERRIDE))
        cam_node.set_initial_state(flat)
        cam_node.set_tag_state_key(SEGMENTATION_TAG)
        self._tagged: set[int] = set()
        self._drawn = False

    def _buffer(self, pipe, name: str, multisamples: int, colour: Texture, depth: Texture | None, host=None):
        fbp = view_framebuffer(multisamples)
        props = WindowProperties.size(self.width, self.height)
        flags = GraphicsPipe.BF_refuse_window
        if host is None:
            buf = self.engine.make_output(pipe, name, 0, fbp, props, flags)
        else:   # share the host's OpenGL context: textures and shaders are prepared once
            buf = self.engine.make_output(pipe, name, 0, fbp, props, flags, host.get_gsg(), host)
        if buf is None:
            raise RendererUnavailable(f"Panda3D could not open a {self.width}×{self.height} offscreen buffer "
                                      f"({multisamples}× MSAA); try multisamples=0")
        # A multisampled buffer is resolved into its texture only when the texture is bound (not by
        # RTM_copy_ram, which reads one sample), so colour is bound and read back after the frame.
        mode = GraphicsOutput.RTM_bind_or_copy if multisamples else GraphicsOutput.RTM_copy_ram
        buf.add_render_texture(colour, mode, GraphicsOutput.RTP_color)
        if depth is not None:
            buf.add_render_texture(depth, GraphicsOutput.RTM_copy_ram, GraphicsOutput.RTP_depth)
        buf.set_clear_color_active(True)
        buf.set_clear_color((*BACKGROUND, 1.0))
        return buf

    def _camera(self, buffer, name: str) -> NodePath:
        node = Camera(name, endoscope_lens(self.width, self.height))
        cam = self.stage.root.attach_new_node(node)
        buffer.make_display_region().set_camera(cam)
        return cam

    def render(self, world_T_eef, depth: bool = False, segmentation: bool = False,
               forward_kinematics: bool = True) -> CameraImage:
        """RGB (always), depth and segmentation (when asked) from the endoscope at ``world_T_eef`` (real);
        ``forward_kinematics=False`` leaves a running episode as it is (see
        :func:`~surrol_data.render.body_shapes.link_world_poses`)."""
        self.stage.update(world_T_eef, forward_kinematics)
        self.stage.place_camera(self._colour_cam)
        need_ids = depth or segmentation
        if need_ids:
            self._tag_new_bodies()
            self.stage.place_camera(self._ids_cam)
        self._ids.set_active(need_ids)
        self.engine.render_frame()
        if not self._drawn:
            # The first frame creates the light's shadow buffer, which is drawn from the next frame on.
            self.engine.render_frame()
            self._drawn = True
        self.engine.extract_texture_data(self._color_tex, self._colour.get_gsg())
        rgb = self._rgb(self._color_tex)
        depth_m = seg = None
        if need_ids:
            if depth:
                z = np.frombuffer(self._depth_tex.get_ram_image(), np.float32).reshape(self.height, self.width)[::-1]
                depth_m = (FAR_M * NEAR_M / (FAR_M - (FAR_M - NEAR_M) * z)).astype(np.float32)
            if segmentation:
                code = self._rgb(self._id_tex).astype(np.int32)
                seg = (code[..., 0] | (code[..., 1] << 8) | (code[..., 2] << 16)) - 1
        return CameraImage(rgb, depth_m, seg)

    def _rgb(self, tex: Texture) -> np.ndarray:
        data = np.frombuffer(tex.get_ram_image_as("RGB"), np.uint8)
        return data.reshape(self.height, self.width, 3)[::-1].copy()

    def _tag_new_bodies(self) -> None:
        cam_node = self._ids_cam.node()
        for body in self.stage.mirror.body_ids:
            if body not in self._tagged:
                cam_node.set_tag_state(str(body), RenderState.make(ColorAttrib.make_flat(_encode(body)), _OVERRIDE))
                self._tagged.add(body)

    def close(self) -> None:
        self.stage.close()
        self.engine.remove_all_windows()

"""The endoscope's own illumination: a spotlight at the scope tip aimed along its axis, and a weak ambient.

An endoscope carries its light down fibre bundles that end beside the lens, so the light moves with the
camera, falls off with the square of distance, and is brightest on the optical axis. The numbers:

* cone: 100° full angle — wider than the 60° field of view, as the illumination field of a laparoscope
  is, so the image corners are lit but dimmer; within the cone the intensity falls as cos(θ)^4
  (``SPOT_EXPONENT``): at the image's 30° edges to about 55 % of the centre, before the longer distance;
* inverse-square falloff; the camera's automatic exposure (every endoscope camera has one) scales the
  light so that the surface on the optical axis receives unit irradiance, whatever its distance
  (``follow``'s ``axis_distance_m``; ``WORKING_DISTANCE_M`` until a surface has been measured);
* the fibre exit sits ``FIBRE_OFFSET_M`` beside the lens (image up): with the light exactly at the eye
  every shadow hides behind its caster; the small offset gives the thin shadow edges surgeons use as a
  depth cue;
* ambient 0.06: the little light that bounces around the cavity.
"""

from __future__ import annotations

from panda3d.core import AmbientLight, NodePath, PerspectiveLens, Point3, Spotlight, Vec3

CONE_DEG = 100.0
SPOT_EXPONENT = 4.0
WORKING_DISTANCE_M = 0.25
FIBRE_OFFSET_M = 0.004
MIN_EXPOSURE_DISTANCE_M, MAX_EXPOSURE_DISTANCE_M = 0.03, 2.0
AMBIENT = 0.06
LIGHT_COLOUR = (1.0, 0.97, 0.92)   # white LED / xenon, slightly warm
SHADOW_MAP_SIZE = 1024   # default; cameras pass about twice their image size (the cone is wider than the view)


class EndoscopeLight:
    """Spotlight + ambient under ``scene`` (a real-metre scene root); ``shadows`` switches shadow mapping."""

    def __init__(self, scene: NodePath, shadows: bool = True, shadow_map_size: int = SHADOW_MAP_SIZE):
        self.spot = Spotlight("endoscope_light")
        self._expose(WORKING_DISTANCE_M)
        self.spot.set_attenuation((0.0, 0.0, 1.0))
        self.spot.set_exponent(SPOT_EXPONENT)
        lens = PerspectiveLens()
        lens.set_fov(CONE_DEG)
        lens.set_near_far(0.005, 2.0)   # shadow-map depth range: the cavity, in metres
        self.spot.set_lens(lens)
        if shadows:
            self.spot.set_shadow_caster(True, shadow_map_size, shadow_map_size)
        self.node = scene.attach_new_node(self.spot)
        scene.set_light(self.node)
        ambient = AmbientLight("cavity_ambient")
        ambient.set_color((AMBIENT, AMBIENT, AMBIENT, 1.0))
        self.ambient = scene.attach_new_node(ambient)
        scene.set_light(self.ambient)

    def _expose(self, distance_m: float) -> None:
        gain = distance_m ** 2
        self.spot.set_color((LIGHT_COLOUR[0] * gain, LIGHT_COLOUR[1] * gain, LIGHT_COLOUR[2] * gain, 1.0))

    def follow(self, eye, forward, up, axis_distance_m: float | None = None) -> None:
        """Put the fibre exit beside the lens at ``eye`` and aim it along ``forward`` (real metres);
        ``axis_distance_m``: how far the optical axis meets a surface (None: keep the last exposure)."""
        if axis_distance_m is not None:
            self._expose(min(max(axis_distance_m, MIN_EXPOSURE_DISTANCE_M), MAX_EXPOSURE_DISTANCE_M))
        pos = [e + FIBRE_OFFSET_M * u for e, u in zip(eye, up)]
        self.node.set_pos(*pos)
        self.node.look_at(Point3(pos[0] + forward[0], pos[1] + forward[1], pos[2] + forward[2]), Vec3(*up))

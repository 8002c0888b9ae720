"""The light of the surgical field: the endoscope's own light at its tip, a shadow light beside it, an ambient.

An endoscope carries its light down fibre bundles that end beside the lens, so the light moves with the
camera, falls off with the square of distance, and is brightest on the optical axis. Being (nearly) at the
eye, it casts shadows that hide behind their casters: a tool 1 cm over the pad, seen from 25 cm with the
fibres 4 mm off the lens, shifts its shadow by a sixth of a millimetre. A shadow the eye can use for depth
needs light from another direction, which is why shadow-casting illumination through a second port is used
to restore the depth cue in laparoscopy. So the field has two lights, both following the scope:

* **the scope light** (``ScopeLight``'s ``spot``): a spotlight at the fibre exit, ``FIBRE_OFFSET_M`` beside the
  lens, aimed along the optical axis; cone 100° full angle (wider than the 60° view, as a laparoscope's
  illumination field is), intensity falling as cos(θ)^``SPOT_EXPONENT`` within it; no shadows (they would be
  invisible, and the shadow pass costs a frame's worth of drawing);
* **the shadow light** (``shadow``): a spotlight ``SHADOW_LIGHT_OFFSET_M`` up and to the left of the lens
  (seen in the image: the light-from-above-left that human vision assumes), aimed at where the optical axis
  meets the scene, carrying ``SHADOW_LIGHT_SHARE`` of the light there; it casts the shadows;
* ambient ``AMBIENT``: the little light that bounces around the cavity.

Inverse-square falloff for both; the camera's automatic exposure (every endoscope camera has one) scales the
lights so that the surface on the optical axis receives unit irradiance whatever its distance (``follow``'s
``axis_distance_m``; ``WORKING_DISTANCE_M`` until a surface has been measured). The shader
(:mod:`~surrol_data.render.phong_shader`) encodes the result with the display's gamma and a soft shoulder, as a
camera does, so that surfaces farther than the axis read dim, not black, and near ones are not burnt white.
"""

from __future__ import annotations

import math

from panda3d.core import (
    AmbientLight,
    DepthWriteAttrib,
    NodePath,
    PerspectiveLens,
    Point3,
    RenderState,
    ShaderAttrib,
    Spotlight,
    Vec3,
)

from surrol_data.render.phong_shader import depth_only_shader

CONE_DEG = 100.0
SPOT_EXPONENT = 2.0
WORKING_DISTANCE_M = 0.25
FIBRE_OFFSET_M = 0.004
MIN_EXPOSURE_DISTANCE_M, MAX_EXPOSURE_DISTANCE_M = 0.03, 2.0
AMBIENT = 0.04
LIGHT_COLOUR = (1.0, 0.97, 0.92)   # white LED / xenon, slightly warm
# The shadow light: its offset from the lens (image up, image left), its share of the light on the optical axis,
# its cone (full angle).
SHADOW_LIGHT_OFFSET_M = (0.07, 0.05)
SHADOW_LIGHT_SHARE = 0.55
SHADOW_CONE_DEG = 90.0
# A node tagged SHADOW_TAG = NO_SHADOW casts no shadow: the shadow light's camera draws it without writing depth.
SHADOW_TAG, NO_SHADOW = "casts_shadow", "no"
SHADOW_MAP_SIZE = 1024   # default; cameras pass about twice their image size (the cone is wider than the view)


def _spot(name: str, cone_deg: float, exponent: float) -> Spotlight:
    spot = Spotlight(name)
    spot.set_attenuation((0.0, 0.0, 1.0))
    spot.set_exponent(exponent)
    lens = PerspectiveLens()
    lens.set_fov(cone_deg)
    lens.set_near_far(0.005, 2.0)   # shadow-map depth range: the cavity, in metres
    spot.set_lens(lens)
    return spot


def _aim(node: NodePath, pos, target, up) -> None:
    node.set_pos(*pos)
    node.look_at(Point3(*target), Vec3(*up))


class EndoscopeLight:
    """The scope light, the shadow light and the ambient under ``scene`` (a real-metre scene root); ``shadows``
    switches the shadow light's shadow mapping."""

    def __init__(self, scene: NodePath, shadows: bool = True, shadow_map_size: int = SHADOW_MAP_SIZE):
        self.spot = _spot("endoscope_light", CONE_DEG, SPOT_EXPONENT)
        self.shadow = _spot("shadow_light", SHADOW_CONE_DEG, 1.0)
        # The shader's lights are ordered by priority (highest first): the scope light is its light 0, the shadow
        # light its light 1, the only one whose shadow map it reads (phong_shader.SHADOW_LIGHT).
        self.spot.set_priority(1)
        self.shadow.set_tag_state_key(SHADOW_TAG)
        # The shadow map is depth only: a trivial shader (overriding the scene's Phong program) writes it.
        depth_only = ShaderAttrib.make(depth_only_shader(), 1000)
        self.shadow.set_initial_state(self.shadow.get_initial_state().add_attrib(depth_only, 1000))
        self.shadow.set_tag_state(NO_SHADOW, RenderState.make(DepthWriteAttrib.make(DepthWriteAttrib.M_off), 1000))
        self._shadows = shadows
        if shadows:
            self.shadow.set_shadow_caster(True, shadow_map_size, shadow_map_size)
        self._distance = WORKING_DISTANCE_M
        self.node = scene.attach_new_node(self.spot)
        self.shadow_node = scene.attach_new_node(self.shadow)
        scene.set_light(self.node)
        scene.set_light(self.shadow_node)
        ambient = AmbientLight("cavity_ambient")
        ambient.set_color((AMBIENT, AMBIENT, AMBIENT, 1.0))
        self.ambient = scene.attach_new_node(ambient)
        scene.set_light(self.ambient)

    @staticmethod
    def _expose(spot: Spotlight, distance_m: float, share: float) -> None:
        gain = share * distance_m ** 2
        spot.set_color((LIGHT_COLOUR[0] * gain, LIGHT_COLOUR[1] * gain, LIGHT_COLOUR[2] * gain, 1.0))

    def follow(self, eye, forward, up, axis_distance_m: float | None = None) -> None:
        """Put the fibre exit beside the lens at ``eye`` aimed along ``forward``, and the shadow light beside the
        scope aimed at the optical axis's surface (real metres); ``axis_distance_m``: how far the optical axis
        meets a surface (None: keep the last exposure)."""
        if axis_distance_m is not None:
            self._distance = min(max(axis_distance_m, MIN_EXPOSURE_DISTANCE_M), MAX_EXPOSURE_DISTANCE_M)
        d = self._distance
        pos = [e + FIBRE_OFFSET_M * u for e, u in zip(eye, up)]
        _aim(self.node, pos, [p + f for p, f in zip(pos, forward)], up)
        right = (forward[1] * up[2] - forward[2] * up[1], forward[2] * up[0] - forward[0] * up[2],
                 forward[0] * up[1] - forward[1] * up[0])
        target = [e + d * f for e, f in zip(eye, forward)]
        above, left = SHADOW_LIGHT_OFFSET_M
        side = [e + above * u - left * r for e, u, r in zip(eye, up, right)]
        _aim(self.shadow_node, side, target, up)
        self._expose(self.spot, d, 1.0 - SHADOW_LIGHT_SHARE)
        # The shadow light's share arrives at an angle: its irradiance there is share × cos(incidence) of a light
        # at its own distance; the exposure holds its share of the on-axis light whatever that distance is.
        side_d = math.dist(side, target)
        self._expose(self.shadow, side_d, SHADOW_LIGHT_SHARE)

    def set_drawing(self, drawing: bool) -> None:
        """Draw the shadow map in the coming frames or not (a view that is not redrawn needs no new map)."""
        if self._shadows:
            self.shadow.set_active(drawing)

    def close(self) -> None:
        self.shadow.set_shadow_caster(False)

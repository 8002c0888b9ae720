"""The endoscope camera: where it looks from, where a world point lands in its image, and what it renders.

The camera sits at the ECM's EEF and looks along the endoscope axis (EEF z), with EEF x as the image's up
direction — as in the reference (``Ecm.render_image``: eye at the EEF link, target 2 cm ahead, up vector =
the EEF link's x axis; 60° field of view, near 1 cm, far 10 m, real units). The EEF link of the reference's
URDF *is* the DH frame 4 of :mod:`surrol_data.envs.ecm_kinematics` (``tests/test_camera_frame.py`` checks the
URDF chain against it), so image up = x4 and image right = y4: an ECM pitched down at a scene shows world
vertical as image up, the far side of the table at the top (:func:`camera_axes`).

Image coordinates are *normalised*: (−1, −1) is the top-left corner, (1, 1) the bottom-right, so they do not
depend on the rendered size.

Until schema camera version 2 the image was turned a quarter turn (up = EEF y: world up at image left). The
ECM tasks' observations (the tracked target's image position) and StaticTrack/ActiveTrack's camera-velocity
actions were defined in that frame, and trained policies and recorded datasets depend on it, so those tasks
keep computing them in it: :func:`tracking_axes`. What is *rendered* uses :func:`camera_axes`.

Rendering uses PyBullet's CPU TinyRenderer with the light coming from the endoscope itself (an endoscope
carries its own light), so what faces the camera is lit whatever the arm's pose.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from surrol_data.envs.physics import pb  # physics imports pybullet quietly

from surrol_data.envs.ecm_kinematics import CAMERA_TARGET_OFFSET_M

FOV_DEG = 60.0
NEAR_M = 0.01
FAR_M = 10.0
TAN_HALF_FOV = math.tan(math.radians(FOV_DEG) / 2)
# The reference's tracking camera (256×256): pixel errors of the tracking tasks are measured at this size.
TRACKING_RESOLUTION = 256


class CameraAxes(NamedTuple):
    """Camera pose in world coordinates (real metres): eye, image right, image down, viewing direction."""
    eye: tuple[float, float, float]
    right: tuple[float, float, float]
    down: tuple[float, float, float]
    forward: tuple[float, float, float]


class CameraImage(NamedTuple):
    rgb: np.ndarray                   # (H, W, 3) uint8
    depth: np.ndarray | None          # (H, W) float32, metres (real) along the view axis
    segmentation: np.ndarray | None   # (H, W) int32, PyBullet body unique id per pixel (−1 = background)


def camera_axes(world_T_eef) -> CameraAxes:
    """The image's axes from the EEF pose (4×4, world, real metres; an array or nested rows): what the
    renderers draw and what teleoperation maps the hand into. Image up is EEF x (the reference's up vector),
    so image down is −x; right = down × forward = y completes the right-handed (right, down, forward) frame."""
    m = world_T_eef
    eye = (float(m[0][3]), float(m[1][3]), float(m[2][3]))
    forward = (float(m[0][2]), float(m[1][2]), float(m[2][2]))
    down = (-float(m[0][0]), -float(m[1][0]), -float(m[2][0]))
    right = (float(m[0][1]), float(m[1][1]), float(m[2][1]))
    return CameraAxes(eye, right, down, forward)


def tracking_axes(world_T_eef) -> CameraAxes:
    """The frame of the ECM tasks' observations and camera-velocity actions: the image frame of
    :func:`camera_axes` turned a quarter turn about the view axis (its right is image down, its down is image
    left; up = EEF y). Kept unchanged so that those tasks' observations, datasets and policies keep their
    meaning; nothing is rendered in it."""
    m = world_T_eef
    eye = (float(m[0][3]), float(m[1][3]), float(m[2][3]))
    forward = (float(m[0][2]), float(m[1][2]), float(m[2][2]))
    down = (-float(m[0][1]), -float(m[1][1]), -float(m[2][1]))
    right = (-float(m[0][0]), -float(m[1][0]), -float(m[2][0]))
    return CameraAxes(eye, right, down, forward)


def project(axes: CameraAxes, point, aspect: float = 1.0) -> tuple[float, float, float]:
    """(x, y, depth) of a world point: x, y normalised image coordinates (±1 at the image edges), depth in
    metres along the view axis. Points behind the camera get a non-positive depth (x, y are then meaningless)."""
    ex, ey, ez = axes.eye
    dx, dy, dz = float(point[0]) - ex, float(point[1]) - ey, float(point[2]) - ez
    r, d, f = axes.right, axes.down, axes.forward
    depth = dx * f[0] + dy * f[1] + dz * f[2]
    if depth <= 1e-9:
        return 0.0, 0.0, depth
    x = (dx * r[0] + dy * r[1] + dz * r[2]) / (depth * TAN_HALF_FOV * aspect)
    y = (dx * d[0] + dy * d[1] + dz * d[2]) / (depth * TAN_HALF_FOV)
    return x, y, depth


def pixel_of(normalised_xy, width: int, height: int) -> tuple[float, float]:
    """Normalised image coordinates → pixel coordinates (column, row) of a ``width``×``height`` image."""
    x, y = normalised_xy
    return (x + 1.0) * width / 2.0, (y + 1.0) * height / 2.0


class EndoscopeCamera:
    """Renders the endoscope's view of a PyBullet scene built ``scene_scale`` times larger than real."""

    def __init__(self, client, size: tuple[int, int] = (128, 128), scene_scale: float = 1.0):
        width, height = _checked_size(size)
        self.client = client
        self.width, self.height = width, height
        self.scene_scale = float(scene_scale)
        self._projection = client.computeProjectionMatrixFOV(
            FOV_DEG, width / height, NEAR_M * scene_scale, FAR_M * scene_scale)

    def render(self, world_T_eef, depth: bool = False, segmentation: bool = False,
               forward_kinematics: bool = True) -> CameraImage:
        """RGB (always), depth and segmentation (when asked) from the endoscope at ``world_T_eef`` (real).
        ``forward_kinematics`` is the Panda3D camera's (TinyRenderer draws each link where the last physics step
        stored it, and changes no episode either way)."""
        axes = camera_axes(world_T_eef)
        s = self.scene_scale
        eye = [v * s for v in axes.eye]
        target = [(e + CAMERA_TARGET_OFFSET_M * f) * s for e, f in zip(axes.eye, axes.forward)]
        up = [-v for v in axes.down]
        view = self.client.computeViewMatrix(eye, target, up)
        # TinyRenderer's light direction points from the scene towards the light: back along the view axis.
        light = [-v for v in axes.forward]
        flags = 0 if segmentation else pb.ER_NO_SEGMENTATION_MASK
        _, _, rgba, zbuffer, seg = self.client.getCameraImage(
            self.width, self.height, view, self._projection, lightDirection=light, shadow=0,
            lightAmbientCoeff=0.5, lightDiffuseCoeff=0.6, lightSpecularCoeff=0.05,
            renderer=pb.ER_TINY_RENDERER, flags=flags)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)[:, :, :3].copy()
        depth_m = None
        if depth:
            z = np.asarray(zbuffer, dtype=np.float64).reshape(self.height, self.width)
            near, far = NEAR_M * s, FAR_M * s
            depth_m = (far * near / (far - (far - near) * z) / s).astype(np.float32)
        seg_ids = None
        if segmentation:
            # PyBullet packs (link + 1) << 24 into the id of multi-link bodies; keep the body id only.
            raw = np.asarray(seg, dtype=np.int64).reshape(self.height, self.width)
            seg_ids = np.where(raw < 0, -1, raw & ((1 << 24) - 1)).astype(np.int32)
        return CameraImage(rgb, depth_m, seg_ids)


def _checked_size(size) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"camera_size must be (width, height) in pixels, got {size!r}") from None
    if not (8 <= width <= 2048 and 8 <= height <= 2048):
        raise ValueError(f"camera_size must be between 8 and 2048 pixels per side, got {size!r}; "
                         "(128, 128) is the default, (256, 256) the reference's")
    return width, height


# Renderers by name: ``camera_renderer=NAME`` builds ``factory(client, size, scene_scale=...)``, an object with
# ``render(world_T_eef, depth=False, segmentation=False) -> CameraImage``. "tiny" is built in; the others plug in
# from outside without envs importing them: by an entry point of the group below (the package declares
# ``panda3d = "surrol_data.render:panda3d_camera"`` in pyproject.toml), loaded the first time its name is asked
# for, or by :func:`register_renderer`.
RENDERER_ENTRY_POINTS = "surrol_data.renderers"
_RENDERERS: dict[str, Callable[..., Any]] = {"tiny": EndoscopeCamera}


def register_renderer(name: str, factory: Callable[..., Any]) -> None:
    """Make ``camera_renderer=name`` build ``factory(client, size, scene_scale=...)``."""
    _RENDERERS[name] = factory


def _renderer_entry_points() -> dict:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=RENDERER_ENTRY_POINTS)}


def camera_renderers() -> tuple[str, ...]:
    """The renderer names ``camera_renderer`` accepts: the built-in and registered ones, then the installed
    entry points."""
    return (*_RENDERERS, *(name for name in _renderer_entry_points() if name not in _RENDERERS))


def make_camera(client, size: tuple[int, int] = (128, 128), scene_scale: float = 1.0, renderer: str = "tiny"):
    """The endoscope camera drawn by ``renderer``: ``"tiny"`` (PyBullet's CPU TinyRenderer, no set-up) or
    ``"panda3d"`` (spotlight, shadows, anti-aliasing; :mod:`surrol_data.render`, found by its entry point and
    imported only then), or any renderer registered by name (see :data:`RENDERER_ENTRY_POINTS`)."""
    factory = _RENDERERS.get(renderer)
    if factory is None:
        found = _renderer_entry_points()
        if renderer not in found:
            hint = "" if found else (f" (no renderer is installed in the entry-point group {RENDERER_ENTRY_POINTS!r}: "
                                     "reinstall surrol-data, e.g. `uv sync` or `pip install -e .`, to declare "
                                     "'panda3d')")
            raise ValueError(f"camera_renderer must be one of {', '.join(camera_renderers())}, got {renderer!r}"
                             + hint)
        factory = _RENDERERS[renderer] = found[renderer].load()
    return factory(client, size, scene_scale=scene_scale)

"""Realistic endoscope rendering with Panda3D: a mirror of any PyBullet scene under the endoscope's light.

* :mod:`~surrol_data.render.scene_mirror` — Panda3D nodes from the scene's visual shapes, poses synced;
* :mod:`~surrol_data.render.body_shapes` — those shapes as meshes and the links' poses, read from PyBullet
  without Panda3D (the Rerun scene uses them too);
* :mod:`~surrol_data.render.endoscope_light` — spotlight at the scope tip, the shadow light beside it, ambient;
* :mod:`~surrol_data.render.phong_shader` — per-pixel Phong shading; :mod:`~surrol_data.render.materials` — looks;
* :mod:`~surrol_data.render.stage` — scene + light + camera placement, shared by every view;
* :mod:`~surrol_data.render.panda_camera` — the offscreen camera behind ``camera_renderer="panda3d"``;
* :mod:`~surrol_data.render.display` — offscreen (EGL) set-up and what to install when it is missing.

Importing this package imports nothing; Panda3D loads with the module that needs it. The envs never import this
package: ``camera_renderer="panda3d"`` finds :func:`panda3d_camera` through the ``surrol_data.renderers`` entry
point that pyproject.toml declares (see :func:`surrol_data.envs.camera.make_camera`).
"""


def panda3d_camera(client, size: tuple[int, int] = (128, 128), scene_scale: float = 1.0):
    """``camera_renderer="panda3d"``: the Panda3D endoscope camera, or :class:`surrol_data.extras.MissingExtra`
    naming the ``render`` extra when Panda3D is not installed."""
    from surrol_data.extras import require

    require("panda3d")
    from surrol_data.render.panda_camera import PandaEndoscopeCamera

    return PandaEndoscopeCamera(client, size, scene_scale=scene_scale)

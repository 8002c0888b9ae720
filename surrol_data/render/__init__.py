"""Realistic endoscope rendering with Panda3D: a mirror of any PyBullet scene under the endoscope's light.

* :mod:`~surrol_data.render.scene_mirror` — Panda3D nodes from the scene's visual shapes, poses synced;
* :mod:`~surrol_data.render.endoscope_light` — spotlight at the scope tip, ambient, shadow map;
* :mod:`~surrol_data.render.phong_shader` — per-pixel Phong shading; :mod:`~surrol_data.render.materials` — looks;
* :mod:`~surrol_data.render.stage` — scene + light + camera placement, shared by every view;
* :mod:`~surrol_data.render.panda_camera` — the offscreen camera behind ``camera_renderer="panda3d"``;
* :mod:`~surrol_data.render.display` — offscreen (EGL) set-up and what to install when it is missing.

Importing this package imports nothing; Panda3D loads with the module that needs it.
"""

"""Where a task env's endoscope is, for renderers outside the env (the GUI, the docs' pictures).

* PSM tasks with ``camera=True``: their still endoscope;
* PSM tasks without: the same endoscope pose computed without adding a body (SurRoL-v2's ECM over the
  scene), so a scene built only for rendering (``render_mode="rgb_array"``) can be viewed;
* ECM tasks: the task's own ECM (its visual bodies are moved to their current poses first).
"""

from __future__ import annotations

from surrol_data.envs.units import SCALING


class EnvEndoscope:
    def __init__(self, env):
        u = env.unwrapped
        if getattr(u, "visual", True) is False:
            # Such a world was built without visual shapes and its PyBullet server without a renderer, where a
            # query of its visual shapes (Panda3D's mirror of the scene makes one) never returns.
            raise ValueError(f"{type(u).__name__} was made without render_mode or camera, so it has nothing to draw; "
                             f"make it with gym.make(..., render_mode='rgb_array')")
        self.env = u
        self.client = u.client
        if getattr(u, "endoscope", None) is not None:
            self.scene_scale = u.endoscope.camera.scene_scale
            self._ecm, self._sync = u.endoscope.ecm, None
        elif getattr(u, "psm", None) is not None:
            from surrol_data.envs.ecm import scene_endoscope_pose

            self.scene_scale = SCALING
            self._ecm, self._sync = _StillPose(scene_endoscope_pose()), None
        else:
            self.scene_scale = 1.0
            self._ecm, self._sync = u.ecm, u._sync_scene

    def pose(self):
        """The endoscope's EEF pose (4×4, world, real metres), with the scene's visual bodies up to date."""
        if self._sync is not None:
            self._sync()
        return self._ecm.eef_world


class _StillPose:
    """The pose of an endoscope that never moves, where :class:`EnvEndoscope` reads an ECM's."""

    def __init__(self, eef_world):
        self.eef_world = eef_world

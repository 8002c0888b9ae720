"""Single-ECM goal-conditioned task: the Gymnasium env that ECMReach, MisOrient, StaticTrack, ActiveTrack specialise.

A task declares its scene (``build_scene``), its initial joints and scene layout (``reset_task``), its goal,
how an action moves the ECM (``apply_action``), what it observes (``observe``), its success test and its
oracle. This class owns the ECM, the camera and the Gymnasium API.

The scene is real size (the reference's ECM scenes are not scaled) and never stepped by PyBullet: the ECM is
integrated in closed form (see :mod:`surrol_data.envs.ecm`) and nothing else moves by physics. PyBullet
holds the bodies so that the endoscope camera (``camera=True``) and ``render_mode="rgb_array"`` see them;
without either, no visual shape is built and nothing is rendered — the tracking tasks project the known
target geometry into the camera analytically (:func:`surrol_data.envs.camera.project`).

Observations are float32, real metres and radians. With ``camera=True`` the observation has one more key,
``"image"``: the endoscope's uint8 (H, W, 3) RGB view at ``camera_size`` (width, height).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from surrol_data.envs import ecm_kinematics as ekin
from surrol_data.envs import physics
from surrol_data.envs.camera import EndoscopeCamera, make_camera
from surrol_data.envs.ecm import ECM_TASK_BASE_PITCH_RAD, ECM_TASK_BASE_POSITION, Ecm, world_T_rcm_from_base
from surrol_data.envs.physics import pb

GROUND_HALF_EXTENTS_M = (2.0, 2.0, 0.01)   # a floor under everything, top at z = 0
GROUND_COLOUR = (0.55, 0.5, 0.45, 1.0)
_JAW = np.zeros(1, dtype=np.float32)       # the ECM has no jaw; metrics and the recorder read zeros


def box(client, half_extents_m, colour, mass: float = 0.0, position_m=(0.0, 0.0, 0.0), yaw: float = 0.0,
        visual: bool = True) -> int:
    """A box body (real-size scene). The ECM scenes never step the physics, so bodies stay where they are put."""
    col = client.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half_extents_m))
    vis = client.createVisualShape(pb.GEOM_BOX, halfExtents=list(half_extents_m), rgbaColor=colour,
                                   specularColor=(0.05, 0.05, 0.05)) if visual else -1
    return client.createMultiBody(mass, col, vis, list(position_m), client.getQuaternionFromEuler([0, 0, yaw]))


def float32(values) -> np.ndarray:
    return np.array(values, dtype=np.float32)


def robot_state(eef_rcm) -> list[float]:
    """EEF pose in the RCM frame: position (m) and extrinsic xyz Euler angles (rad) — the reference's 6 values."""
    return [eef_rcm[0][3], eef_rcm[1][3], eef_rcm[2][3], *ekin.euler_xyz(eef_rcm)]


class EcmEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    TASK = ""                       # natural-language description (stored with every recorded frame)
    ACTION_DIM = 3
    OBS_DIM = 6
    GOAL_DIM = 3
    INITIAL_JOINTS = (0.0, 0.0, 0.05, 0.0)   # the reference's default ECM pose (QPOS_ECM)
    SUBSTEPS = physics.ECM_SUBSTEPS          # motor steps per env step (0.1 s)

    def __init__(self, render_mode: str | None = None, render_size: tuple[int, int] = (480, 360),
                 camera: bool = False, camera_size: tuple[int, int] = (128, 128), camera_renderer: str = "tiny"):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = render_size
        # Visual shapes matter only to a renderer: build them only when something renders.
        self.visual = render_mode is not None or bool(camera)
        self.client = physics.make_client(gui=False)
        box(self.client, GROUND_HALF_EXTENTS_M, GROUND_COLOUR, position_m=(0.0, 0.0, -GROUND_HALF_EXTENTS_M[2]),
            visual=self.visual)
        self.ecm = Ecm(world_T_rcm_from_base(ECM_TASK_BASE_POSITION, ECM_TASK_BASE_PITCH_RAD),
                       client=self.client, visual=self.visual)
        # camera_renderer: "tiny" (PyBullet's TinyRenderer) or "panda3d" (spotlight, shadows, anti-aliasing).
        self.camera = make_camera(self.client, camera_size, renderer=camera_renderer) if camera else None
        self.goal = np.zeros(self.GOAL_DIM)
        self._goal32 = float32(self.goal)
        self.build_scene()

        box_space = lambda n: spaces.Box(-np.inf, np.inf, shape=(n,), dtype=np.float32)  # noqa: E731
        obs_spaces = {"observation": box_space(self.OBS_DIM), "achieved_goal": box_space(self.GOAL_DIM),
                      "desired_goal": box_space(self.GOAL_DIM)}
        if self.camera is not None:
            obs_spaces["image"] = spaces.Box(0, 255, shape=(self.camera.height, self.camera.width, 3), dtype=np.uint8)
        self.observation_space = spaces.Dict(obs_spaces)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.ACTION_DIM,), dtype=np.float32)

    # ------------------------------------------------------------------ to be declared by tasks
    def build_scene(self) -> None:
        """Create the task's bodies (once; :meth:`reset_task` only moves them)."""

    def reset_task(self, rng: np.random.Generator) -> tuple[float, float, float, float]:
        """Lay out the scene for a new episode; return the ECM's initial joints."""
        return self.INITIAL_JOINTS

    def sample_goal(self, rng: np.random.Generator) -> np.ndarray:
        return np.zeros(self.GOAL_DIM)

    def apply_action(self, action: list[float]) -> None:
        """Set the ECM's joint targets for an action (already clipped to [-1, 1], plain floats)."""
        raise NotImplementedError

    def action_axes(self) -> np.ndarray | None:
        """World directions (3×3, one column per axis) of the action's x, y, z position terms now, for
        teleoperation to map the hand from the image into; None when the action moves no position (a roll)."""
        return None

    def endoscope_pose(self) -> list[list[float]]:
        """The EEF pose (4×4, world, real metres) of the endoscope the operator watches: the task's ECM."""
        return self.ecm.eef_world

    def advance_scene(self) -> None:
        """Move what moves by itself (ActiveTrack's target), once per env step after the ECM."""

    def observe(self) -> tuple[list[float], list[float]]:
        """(observation, achieved goal) as float lists."""
        raise NotImplementedError

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        raise NotImplementedError

    def is_terminated(self, obs: dict) -> bool:
        return False

    def sync_bodies(self) -> None:
        """Put moving bodies at their current poses before a render (only scenes that render call this)."""

    def oracle_action(self, obs: dict) -> np.ndarray:
        raise NotImplementedError

    # ------------------------------------------------------------------ Gymnasium API
    def compute_reward(self, achieved_goal, desired_goal, info=None):
        """Sparse reward is_success − 1; works on single goals and on batches (HER relabelling)."""
        return self.is_success(achieved_goal, desired_goal).astype(np.float32) - 1.0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        joints = self.reset_task(self.np_random)
        self.ecm.reset_joints(joints)
        self.goal = np.asarray(self.sample_goal(self.np_random), dtype=np.float64)
        self._goal32 = float32(self.goal)
        self.after_reset()
        obs = self._get_obs()
        return obs, self._info(obs)

    def after_reset(self) -> None:
        """Task state that depends on the reset ECM pose and goal (reference camera, oracle memory)."""

    def step(self, action):
        # Clipped as plain floats: a handful of numbers, where numpy's per-call cost would dominate the step.
        action = [min(1.0, max(-1.0, v)) for v in np.asarray(action, dtype=np.float64).reshape(self.ACTION_DIM).tolist()]
        self.apply_action(action)
        self.ecm.advance(self.SUBSTEPS)
        self.advance_scene()
        obs = self._get_obs()
        info = self._info(obs)
        return obs, self.step_reward(obs, info), self.is_terminated(obs), False, info

    def step_reward(self, obs: dict, info: dict) -> float:
        """compute_reward of this step; the sparse one is is_success − 1, already known from ``info``."""
        return info["is_success"] - 1.0

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        self._sync_scene()
        w, h = self.render_size
        # The reference's overview: from behind-left of the ECM, looking at the workspace.
        view = self.client.computeViewMatrixFromYawPitchRoll([0.27, -0.20, 0.55], 1.8, 150, -30, 0, 2)
        proj = self.client.computeProjectionMatrixFOV(45, w / h, 0.1, 20.0)
        img = self.client.getCameraImage(w, h, view, proj, renderer=pb.ER_TINY_RENDERER,
                                         flags=pb.ER_NO_SEGMENTATION_MASK)[2]
        return np.asarray(img, dtype=np.uint8).reshape(h, w, 4)[:, :, :3]

    def render_endoscope(self, size: tuple[int, int] | None = None, depth: bool = False, segmentation: bool = False):
        """The endoscope's view (RGB, and depth/segmentation when asked) at ``size`` (default: ``camera_size``).

        Works whether or not ``camera=True``; without visual shapes (no camera, no render_mode) objects are
        invisible, so ask for ``camera=True`` or a render_mode to see them."""
        cam = self.camera if size is None and self.camera is not None else EndoscopeCamera(self.client, size or (128, 128))
        self._sync_scene()
        return cam.render(self.ecm.eef_world, depth=depth, segmentation=segmentation)

    def close(self):
        if getattr(self, "client", None) is not None:
            self.client.disconnect()
            self.client = None

    # ------------------------------------------------------------------ internals
    def _sync_scene(self) -> None:
        self.ecm.sync_visual()
        self.sync_bodies()

    def _get_obs(self) -> dict:
        state, achieved = self.observe()
        obs = {"observation": float32(state), "achieved_goal": float32(achieved), "desired_goal": self._goal32.copy()}
        if self.camera is not None:
            self._sync_scene()
            obs["image"] = self.camera.render(self.ecm.eef_world).rgb
        return obs

    def _info(self, obs: dict) -> dict:
        return {"is_success": float(self.is_success(obs["achieved_goal"], obs["desired_goal"])),
                "tip_position": float32([self.ecm.tip_position_world()]),
                "jaw_angle": _JAW.copy()}

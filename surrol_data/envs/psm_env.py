"""Single-PSM goal-conditioned task: the Gymnasium env that NeedleReach, NeedlePick, … specialise.

A task is a small subclass that declares its scene (``build_scene``), its episode set-up and goal
sampling (``reset_task``), what it observes of its object, its achieved goal, and its scripted oracle.
This class owns the arm, the action mapping, the grasp-by-constraint and the Gymnasium API.

Action (5,): (dx, dy, dz, dyaw, jaw) in [-1, 1]; 1 = 1 cm of tool-tip motion and 30° of yaw per step;
jaw < 0 closes (and grasps when both jaws touch the object), jaw ≥ 0 opens to 40° (and releases).
"""

from __future__ import annotations

import numpy as np
import gymnasium as gym
from gymnasium import spaces

from surrol_data.envs import kinematics as kin
from surrol_data.envs import objects, physics
from surrol_data.envs.adaptive_steps import SubstepPlanner
from surrol_data.envs.ecm import SceneEndoscope, scene_endoscope_pose
from surrol_data.envs.free_motion import FreeMotion
from surrol_data.envs.grasp import Grasp
from surrol_data.envs.numeric import clip, norm
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import Psm
from surrol_data.envs.units import ACTION_POSITION_M, ACTION_YAW_RAD, SCALING, SUCCESS_TOLERANCE_M

# PSM1's remote centre of motion (real metres) and the tip workspace the tasks sample from.
PSM1_RCM = np.array([0.507, 0.0736, 0.8524])
# The RCM frame's yaw about the vertical: the reference's base placement (PSM1 −110°, PSM2 −70°), so joint values
# match the dVRK's for the same tip pose. Commands are Cartesian and the IK is exact either way, so only how a move
# splits over the joints changes. Measured turned vs unturned (same seeds): the same 40 random actions put the tip
# 0.6 µm apart after one step, 0.3 mm after 40; the worst unit-box tracking error per PSM task (physics_realism's
# tracking scenario, 30 moves) at most 2.76 % vs 2.71 %, no task's 0.06 points apart; oracle success over seeds
# 0–99 unchanged on all 15 tasks; the simulated operators (seeds 0–19, both skills, the 11 PSM tasks) 407 vs 401
# successes of 440, 428 attempts ending the same way. Their outcomes once seemed to change with it (NeedlePick
# novice 4 of 8 episodes instead of 7): the operator keyed its noise by the first observation's bits, see
# collect/operator's episode_key. False builds the RCM frames unturned (world-aligned), as before.
USE_REFERENCE_BASE_YAW = True
REFERENCE_PSM1_BASE_YAW_RAD = float(np.deg2rad(-110.0))
REFERENCE_PSM2_BASE_YAW_RAD = float(np.deg2rad(-70.0))
PSM1_BASE_YAW_RAD = REFERENCE_PSM1_BASE_YAW_RAD if USE_REFERENCE_BASE_YAW else 0.0
PSM2_BASE_YAW_RAD = REFERENCE_PSM2_BASE_YAW_RAD if USE_REFERENCE_BASE_YAW else 0.0
WORKSPACE = np.array([[0.50, 0.60], [-0.05, 0.05], [0.675, 0.745]])
# Commanded tip targets may leave the sampling workspace by this much (low side, high side): the reference's
# margins (±0.02 xy, +0.08 z) are in its scaled units, i.e. ±4 mm / +16 mm real.
WORKSPACE_MARGIN = np.array([[0.02, 0.02], [0.02, 0.02], [0.0, 0.08]]) / SCALING


def tip_clip_box(workspace: np.ndarray = WORKSPACE) -> np.ndarray:
    """Where commanded tip targets are clipped to (rows x/y/z as [low, high], real metres): ``workspace`` widened by
    WORKSPACE_MARGIN. Whatever the tool pushes can go no further than its xy (the rim of a scene of loose objects)."""
    return np.stack([workspace[:, 0] - WORKSPACE_MARGIN[:, 0], workspace[:, 1] + WORKSPACE_MARGIN[:, 1]], axis=1)


_TARGET_LOW, _TARGET_HIGH = (np.ascontiguousarray(side) for side in tip_clip_box().T)
# Tool-down tip frame: columns are tip x (wrist-yaw axis), tip y (jaw-opening direction), tip z (down).
_TOOL_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_TOOL_DOWN_T = _TOOL_DOWN.T


def tip_orientation_features(rotation: np.ndarray) -> np.ndarray:
    """Euler xyz (rad) of the tip rotation relative to the tool-down frame: (0, 0, yaw) when pointing down.

    Measuring relative to tool-down keeps the features continuous where plain world Euler angles of a
    downward-pointing frame would flip between ±π.
    """
    return kin.euler_xyz(rotation.dot(_TOOL_DOWN_T))   # (.dot: see kinematics)


def tool_down(yaw: float) -> np.ndarray:
    return kin.rot_z3(yaw).dot(_TOOL_DOWN)


# Pitch mode: one unit of action tilts the tool 15° (the reference's pitch step), within ±90° of vertical.
ACTION_PITCH_RAD = np.deg2rad(15.0)
PITCH_LIMIT_RAD = np.pi / 2
ROTATION_MODES = ("yaw", "pitch")


def tilted_tool(pitch: float) -> np.ndarray:
    """Tip rotation of a pitch-mode arm: the tool-down frame (jaw opening along world x) tilted about world x.

    A positive pitch swings the tip's approach direction towards +y.
    """
    c, s = np.cos(pitch), np.sin(pitch)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) @ tool_down(0.0)


def approach_direction(pitch: float) -> np.ndarray:
    """Unit vector along which a pitch-mode tool points (wrist → jaw tips), world frame."""
    return tilted_tool(pitch)[:, 2]


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class PsmEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 5}

    TASK = ""                 # natural-language description (stored with every recorded frame)
    OBJECT_OBS = True         # 19-D observation with object terms (else 7-D)
    BLOCK_JAW = False         # jaw forced closed, no grasping (NeedleReach)
    FIXED_YAW = False         # yaw action ignored
    # "yaw": d_rot turns the downward tool about the vertical (30° per unit); "pitch": it tilts the tool about
    # world x (15° per unit, jaw opening along world x), reported as the orientation's roll term.
    ROTATION_MODE = "yaw"
    ORACLE_GAIN = 0.4
    ORACLE_TURN_GAIN = 0.4    # the oracle's largest rotation action per step
    ACTION_DIM = 5            # per arm 5; the bimanual base sets 10
    OBSERVATION_DIM = 0       # 0: 19 with object terms, else 7; the bimanual base sets 35
    GOAL_DIM = 3              # a point (the goal marker shows its first three terms)
    # Carry a welded object kinematically while nothing can come near it (grasp.py, 6. Carry; adaptive_steps
    # .CARRY_CLEAR_HELD_OBJECTS): set by the tasks whose carry has been checked against the weld.
    KINEMATIC_CARRY = False
    # The most a fast object near another body may travel per physics step (adaptive_steps.py), real metres.
    OBJECT_TRAVEL_PER_STEP_M = physics.MAX_OBJECT_TRAVEL_PER_STEP_M
    # Instrumentation: when set (on an instance), called as ``substep_hook(env)`` after every physics substep
    # (benchmarks/physics_realism.py probes contacts there). Unset, it costs one attribute test per substep.
    substep_hook = None
    _closing: tuple = ()      # grasps whose jaws close during the current step (they may grip at any substep)
    _constraint_erp = physics.DEFAULT_CONSTRAINT_ERP   # the world's non-contact ERP now (see _step_physics)
    _features_memo: dict | None = None   # id(tip pose) → (pose, its orientation features), see _orientation_features

    def __init__(self, render_mode: str | None = None, render_size: tuple[int, int] = (480, 360),
                 camera: bool = False, camera_size: tuple[int, int] = (128, 128), camera_renderer: str = "tiny"):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = render_size
        # Visual shapes cost most of a rebuild and matter only to a renderer: build them only when one is used.
        self.visual = render_mode is not None or bool(camera)
        self.client = physics.make_client(gui=render_mode == "human", renderer=self.visual)
        self._build_world()
        # camera=True: a still, non-colliding ECM over the scene whose endoscope image joins the observation.
        # camera_renderer: "tiny" (PyBullet's TinyRenderer) or "panda3d" (spotlight, shadows, anti-aliasing).
        self.endoscope = SceneEndoscope(self.client, camera_size, scene_scale=SCALING,
                                        renderer=camera_renderer) if camera else None
        self._tip = np.eye(4)
        self.goal = np.zeros(self.GOAL_DIM)
        self._waypoints: list[dict] = []
        self._wp_index = 0
        self._hold = 0

        obs_dim = self.OBSERVATION_DIM or (19 if self.OBJECT_OBS else 7)
        box = lambda n: spaces.Box(-np.inf, np.inf, shape=(n,), dtype=np.float32)  # noqa: E731
        self.observation_space = spaces.Dict(
            {"observation": box(obs_dim), "achieved_goal": box(self.GOAL_DIM),
             "desired_goal": box(self.GOAL_DIM)})
        if self.endoscope is not None:
            w, h = self.endoscope.size
            self.observation_space["image"] = spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.ACTION_DIM,), dtype=np.float32)

    def _build_world(self) -> None:
        objects.make_table(self.client, visual=self.visual)
        self.psm = Psm(self.client, PSM1_RCM, PSM1_BASE_YAW_RAD, visual=self.visual)
        self.object_id = -1
        self.build_scene()
        self.goal_marker = objects.make_goal_marker(self.client, visual=self.visual)
        self.grasp = Grasp(self.client, self.psm, self.object_id, self.grasp_lift_condition)
        self._substeps = SubstepPlanner(self.client, (self.grasp,), self.dynamic_bodies, carry=self.KINEMATIC_CARRY,
                                        object_travel_m=self.OBJECT_TRAVEL_PER_STEP_M)

    # ------------------------------------------------------------------ to be declared by tasks
    def build_scene(self) -> None:
        raise NotImplementedError

    def respawn_objects(self) -> None:
        """Replace the task's dynamic bodies by fresh ones (see :meth:`reset`)."""

    def reset_task(self, rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
        """Place objects (without simulating); return the initial tip position, yaw and jaw angle."""
        raise NotImplementedError

    def sample_goal(self, rng: np.random.Generator) -> np.ndarray:
        """The desired goal, drawn after the scene has settled."""
        raise NotImplementedError

    def object_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(object position, waypoint position, object Euler), real metres / rad."""
        raise NotImplementedError

    def achieved_goal(self) -> np.ndarray:
        raise NotImplementedError

    def plan_oracle(self) -> list[dict]:
        """Waypoints for the oracle, computed at reset from the settled scene."""
        return []

    def goal_marker_position(self) -> np.ndarray:
        """Where the green goal sphere is drawn (real metres): the goal, for tasks whose goal is one point."""
        return self.goal[:3]

    def grasp_lift_condition(self) -> bool:
        """The task's condition for welding an object the blades hold (reference §3), e.g. the needle lifted
        5 mm by the squeezing jaws. ``object_start_z`` is the achieved goal's height when the episode began."""
        return True

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        d = norm(np.asarray(achieved_goal) - np.asarray(desired_goal))
        return d < SUCCESS_TOLERANCE_M

    # ------------------------------------------------------------------ Gymnasium API
    def compute_reward(self, achieved_goal, desired_goal, info=None):
        """Sparse reward is_success − 1; works on single goals and on batches (HER relabelling)."""
        return self.is_success(achieved_goal, desired_goal).astype(np.float32) - 1.0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.grasp.release()
        self.grasp.drops = 0
        # Fresh dynamic bodies every episode: PyBullet keeps hidden per-body state (solver warm starts,
        # sleeping timers) that neither resetting poses nor restoring a saved state clears, and equal seeds
        # must give equal episodes bit for bit. Their shapes are reused; the whole reset takes about 2 ms.
        self.psm.respawn()
        self.respawn_objects()
        self.grasp.object_id = self.object_id
        tip, yaw, jaw = self.reset_task(self.np_random)
        sol = self.psm.ik(kin.pose_from(tip, self.tool_rotation(yaw)))
        if not sol.within_limits:
            raise RuntimeError(f"initial tip position {tip} is outside the PSM's reach; check the task's workspace")
        self.psm.reset_joints(sol.q, jaw)
        self.simulate(physics.SETTLE_STEPS)
        if self.object_id >= 0:
            # The settled object sleeps until something touches it (Bullet wakes it on contact): a resting
            # object's contacts are most of a step's physics cost.
            self.client.changeDynamics(self.object_id, -1, activationState=physics.pb.ACTIVATION_STATE_SLEEP)
        return self._start_episode()

    def _start_episode(self):
        """After the scene has settled: draw the goal, plan the oracle, and return the first (obs, info)."""
        self.goal = np.asarray(self.sample_goal(self.np_random), dtype=np.float64)
        self.object_start_z = float(self.achieved_goal()[2])
        if self.goal_marker >= 0:
            marker = self.goal_marker_position()
            self.client.resetBasePositionAndOrientation(self.goal_marker, (marker * SCALING).tolist(), [0, 0, 0, 1])
        self._waypoints = self.plan_oracle()
        self._wp_index = 0
        self._hold = 0
        obs = self._get_obs()
        return obs, self._info(obs)

    def step(self, action):
        action = clip(np.asarray(action, dtype=np.float64).reshape(5), -1.0, 1.0)
        self._apply_action(action)
        closing = not self.BLOCK_JAW and action[4] < 0
        self._closing = (self.grasp,) if closing else ()
        self.simulate(physics.SUBSTEPS)
        self._closing = ()
        if not self.BLOCK_JAW:
            self.grasp.update(closing=closing)
        obs = self._get_obs()
        info = self._info(obs)
        return obs, self._step_reward(obs, info), False, False, info

    def _step_reward(self, obs: dict, info: dict) -> float:
        """The step's reward: with the default sparse reward, is_success − 1 from the info's success (the same
        test on the same goals, not made twice)."""
        if type(self).compute_reward is PsmEnv.compute_reward:
            return info["is_success"] - 1.0
        return float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"]))

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        w, h = self.render_size
        target = np.array([0.55, 0.0, 0.69]) * SCALING
        view = self.client.computeViewMatrixFromYawPitchRoll(target.tolist(), 0.25 * SCALING, 90, -35, 0, 2)
        proj = self.client.computeProjectionMatrixFOV(45, w / h, 0.01 * SCALING, 2.0 * SCALING)
        img = self.client.getCameraImage(w, h, view, proj, renderer=self.client.ER_TINY_RENDERER)[2]
        return np.asarray(img, dtype=np.uint8).reshape(h, w, 4)[:, :, :3]

    def close(self):
        if getattr(self, "client", None) is not None:
            self.client.disconnect()
            self.client = None

    # ------------------------------------------------------------------ internals
    def simulate(self, steps: int) -> None:
        """Advance the physics and refresh the cached tip pose (read by observation, action and oracle)."""
        self._step_physics(steps, self._closing)
        self._tip = self.psm.tip_pose()

    def dynamic_bodies(self) -> list[int]:
        """The scene's movable objects (the adaptive sub-stepping watches their speed)."""
        return [self.object_id] if self.object_id >= 0 else []

    def _step_physics(self, steps: int, closing: tuple[Grasp, ...] = ()) -> None:
        """``steps`` physics substeps, each split into finer ones where something fast is about to hit something
        (see adaptive_steps); the grasps of closing jaws in ``closing`` may grip after any of them."""
        hook = self.substep_hook
        watched = [g for g in closing if not g.attached]
        cid = self.client._client
        step_simulation = pb.stepSimulation
        planner = self._substeps
        arms = [grasp.psm for grasp in planner.grasps]
        planner.plan_tools(physics.TIME_STEP, watched)
        carried = planner.carried
        # Held objects' slip and press-in, watched after every physics step (Grasp.gives; a carried object has
        # neither).
        holding = [g for g in planner.grasps if g.attached and not g.carried]
        erp = physics.CONSTRAINT_ERP if any(g.constraint is not None for g in planner.grasps) else \
            physics.DEFAULT_CONSTRAINT_ERP
        if erp != self._constraint_erp:   # (the weld's stiffness: see physics.CONSTRAINT_ERP)
            self._constraint_erp = erp
            self.client.setPhysicsEngineParameter(erp=erp)
        movable = set(self.dynamic_bodies()).union(arm.body for arm in arms) if watched or holding else ()
        for psm in arms:
            psm.plan_gravity_compensation()
        if planner.free_arm is not None and self._move_free(planner.free_arm, steps, hook):
            return
        steady_k = planner.steady_refinement(steps)
        k_now = 1
        for i in range(steps):
            if i < physics.RAMP_STEPS:   # (a ramp ends at its last step: later calls would do nothing)
                for psm in arms:
                    psm.ramp_targets(i)
            k = steady_k or planner.refinement(physics.TIME_STEP)
            if k != k_now:
                k_now = k
                self._set_time_step(physics.TIME_STEP / k)
            for _ in range(k):
                for psm in arms:
                    psm.compensate_gravity()
                for grasp in carried:
                    grasp.load_wrist()
                step_simulation(cid)
                if carried and hook is not None:
                    for grasp in carried:   # (a probe sees the carried object where it is at every step)
                        grasp.follow_seen()
                if holding:
                    holding = [g for g in holding if g.attached and not g.gives(movable, physics.TIME_STEP / k_now)]
                if watched:
                    gripped = [g for g in watched if g.grip_if_between()]
                    if gripped:
                        watched = [g for g in watched if g not in gripped]
                        holding += gripped
                if hook is not None:
                    hook(self)
        for grasp in carried:
            grasp.follow()
        if k_now != 1:
            self._set_time_step(physics.TIME_STEP)

    def _move_free(self, grasp, steps: int, hook) -> bool:
        """The period for an arm that touches nothing and carries the only object (SubstepPlanner.free_arm): moved by
        its motors' closed-form rule (free_motion.py) where that rule holds (FreeMotion.plan); else False."""
        motion = FreeMotion.plan(grasp.psm, self._substeps.joint_states(grasp.psm, physics.TIME_STEP), steps,
                                 physics.TIME_STEP, grasp.load_torque)
        if motion is None:
            return False
        self._substeps.free_periods += 1
        if hook is not None:   # (a probe sees every physics step's state)
            for i in range(steps):
                motion.set_step(i)
                grasp.follow()
                hook(self)
        else:
            motion.set_step(steps - 1)
        grasp.psm.finish_ramp(steps)
        grasp.follow()
        return True

    def _set_time_step(self, dt: float) -> None:
        """Change the physics step and re-issue the motor commands: PyBullet turns a motor's force limit into an
        impulse limit with the step current when the command is given, so under a k-times finer step the old
        commands pushed k times harder than their limit (a tool pressed a block 5 mm into the board)."""
        self.client.setPhysicsEngineParameter(fixedTimeStep=dt)
        for grasp in self._substeps.grasps:
            grasp.psm.reapply_motors()
        self.reapply_scene_motors()

    def reapply_scene_motors(self) -> None:
        """Re-issue the motor commands of the scene's own joints after a change of time step (see
        _set_time_step); a task with such joints (a drawer's friction) overrides this."""

    def tip_pose(self) -> np.ndarray:
        return self._tip

    def action_axes(self, arm: int = 0) -> np.ndarray:
        """World directions (3×3, one column per axis) of arm ``arm``'s action x, y, z: the world's own, for
        every PSM task (1 = 1 cm of tip motion along world x, y, z)."""
        return np.eye(3)

    def endoscope_pose(self) -> list[list[float]]:
        """The EEF pose (4×4, world, real metres) of the endoscope the operator watches: the ``camera=True``
        endoscope, or the same still pose when the env renders no camera (:data:`~surrol_data.envs.ecm.
        PSM_SCENE_JOINTS`)."""
        if self.endoscope is not None:
            return self.endoscope.ecm.eef_world
        return scene_endoscope_pose()

    def _apply_action(self, action: np.ndarray) -> None:
        pose = self._tip
        target = pose[:3, 3] + action[:3] * ACTION_POSITION_M
        target = clip(target, _TARGET_LOW, _TARGET_HIGH)
        features = self._tip_features()
        if self.ROTATION_MODE == "pitch":
            angle = float(min(max(features[0] + action[3] * ACTION_PITCH_RAD, -PITCH_LIMIT_RAD), PITCH_LIMIT_RAD))
        else:
            angle = features[2] + (0.0 if self.FIXED_YAW else action[3] * ACTION_YAW_RAD)
        self.psm.command_tip(kin.pose_from(target, self.tool_rotation(angle)), ramp=True)
        if self.BLOCK_JAW or action[4] < 0:
            self.psm.command_jaw(physics.JAW_CLOSED_RAD)
        else:
            self.psm.command_jaw(physics.JAW_OPEN_RAD)

    def tool_rotation(self, angle: float) -> np.ndarray:
        """Tip rotation for the controlled angle (yaw, or tilt in pitch mode)."""
        return tilted_tool(angle) if self.ROTATION_MODE == "pitch" else tool_down(angle)

    @property
    def angle_index(self) -> int:
        """Where the controlled angle sits in the observation (orientation roll term in pitch mode, else yaw)."""
        return 3 if self.ROTATION_MODE == "pitch" else 5

    def _orientation_features(self, pose: np.ndarray) -> np.ndarray:
        """tip_orientation_features of a tip pose the env keeps (the observation and the next action both need
        them: computed once per pose object; the env's poses are fresh arrays, never changed). Read only."""
        memo = self._features_memo
        if memo is None:
            memo = self._features_memo = {}
        hit = memo.get(id(pose))
        if hit is not None and hit[0] is pose:
            return hit[1]
        if len(memo) >= 4:
            memo.clear()
        features = tip_orientation_features(pose[:3, :3])
        memo[id(pose)] = (pose, features)
        return features

    def _tip_features(self) -> np.ndarray:
        return self._orientation_features(self._tip)

    def robot_state(self) -> np.ndarray:
        pose = self._tip
        return np.concatenate([pose[:3, 3], self._tip_features(), [self.psm.jaw_angle()]])

    def observation_vector(self) -> np.ndarray:
        """The flat state: the arm's terms, then (object tasks) the object's. The bimanual base overrides it."""
        robot = self.robot_state()
        if not self.OBJECT_OBS:
            return robot
        pos, wp, euler = self.object_state()
        return np.concatenate([robot, pos, pos - robot[:3], wp, euler])

    def _get_obs(self) -> dict:
        state = self.observation_vector()
        obs = {"observation": state.astype(np.float32),
               "achieved_goal": self.achieved_goal().astype(np.float32),
               "desired_goal": self.goal.astype(np.float32)}
        if self.endoscope is not None:
            obs["image"] = self.endoscope.image()
        return obs

    def _info(self, obs: dict, success=None) -> dict:
        """The step's info; ``success``: the task's is_success of the observation's goals, when the caller has it."""
        if success is None:
            success = self.is_success(obs["achieved_goal"], obs["desired_goal"])
        return {"is_success": float(success),
                "tip_position": obs["observation"][None, :3].copy(),
                "jaw_angle": obs["observation"][None, 6].copy(),
                "grasped": self.grasp.attached, "drops": self.grasp.drops}

    # ------------------------------------------------------------------ oracle
    @property
    def oracle_waypoints(self) -> list[dict]:
        """The oracle's plan for this episode (made at reset): dicts with ``target`` (a tip position in metres,
        or a callable of the observation for closed-loop waypoints), ``yaw``, ``jaw`` and tolerances. Other
        agents that know the task's steps (the simulated operator) follow the same plan their own way."""
        return list(self._waypoints)

    def oracle_action(self, obs: dict) -> np.ndarray:
        """Scripted linear-waypoint policy: move the tip towards the next waypoint at most ``ORACLE_GAIN`` cm
        per axis per step, turn the yaw towards the waypoint's, set the jaw; a waypoint is done when the tip
        is within its tolerance (and, for closing waypoints, after the jaw had time to close)."""
        while self._wp_index < len(self._waypoints):
            wp = self._waypoints[self._wp_index]
            action, reached = self._waypoint_action(wp, obs)
            if reached and self._hold >= wp.get("hold", 0):
                self._wp_index += 1
                self._hold = 0
                continue
            if reached:
                self._hold += 1
            return action
        return self._idle_action()

    def _waypoint_action(self, wp: dict, obs: dict) -> tuple[np.ndarray, bool]:
        """The oracle's action towards waypoint ``wp`` and whether the tip is already within its tolerances."""
        state = obs["observation"]
        tip, yaw = state[:3].astype(np.float64), float(state[self.angle_index])
        target = wp["target"](obs) if callable(wp["target"]) else wp["target"]
        err = target - tip
        yaw_err = float(wrap_angle(wp.get("yaw", yaw) - yaw))
        reached = np.linalg.norm(err) < wp.get("tol", 1e-3) and abs(yaw_err) < wp.get("yaw_tol", 0.05)
        delta = err / ACTION_POSITION_M
        delta = delta / max(1.0, np.abs(delta).max()) * wp.get("gain", self.ORACLE_GAIN)
        unit = ACTION_PITCH_RAD if self.ROTATION_MODE == "pitch" else ACTION_YAW_RAD
        d_yaw = np.clip(yaw_err / unit, -self.ORACLE_TURN_GAIN, self.ORACLE_TURN_GAIN)
        return np.array([*delta, d_yaw, wp["jaw"]], dtype=np.float32), reached

    def _idle_action(self) -> np.ndarray:
        """After the last waypoint: hold still with the last waypoint's jaw."""
        return np.array([0, 0, 0, 0, self._waypoints[-1]["jaw"] if self._waypoints else 0.5], dtype=np.float32)

"""Two-PSM goal-conditioned task: the Gymnasium env that NeedleRegrasp and BiPegTransfer specialise.

It reuses :class:`~surrol_data.envs.psm_env.PsmEnv` for the client, the spaces, rendering and the goal API,
and replaces the single arm by the pair PSM1 (+y side) and PSM2 (−y side), each with its own grasp.

Action (10,): ``[PSM1 (dx, dy, dz, d_rot, jaw) | PSM2 (dx, dy, dz, d_rot, jaw)]`` in [-1, 1]; 1 = 1 cm of
tool-tip motion per step; jaw < 0 closes (and grasps when both jaws touch the object), ≥ 0 opens (releases).
``d_rot`` depends on the arm's rotation mode: ``"yaw"`` turns the downward tool about the vertical by
30° per unit (as the single-arm tasks); ``"pitch"`` tilts the tool about the world x axis by 15° per unit,
with the jaw opening along world x (the reference's pitch mode, used to pass a needle held upright).
A hand-over is just the two grasps at work: the receiving arm closes on the object and squeezes it with its
blades, which keep colliding with it, while the giving arm's constraint still drives it; the giving arm opens,
and the receiving arm's grasp takes the object where it sits between its blades (one constraint at a time: see
grasp.py, 5. Hand-over). A held object does not collide with the jaws whose constraint holds it (their contacts
would only push against the constraint), and the world is rebuilt every episode, which keeps equal seeds
bit-exact whatever earlier episodes did.

Observation (35,), real metres and radians: PSM1 (tip xyz, tip orientation (roll, pitch, yaw) relative to
the tool-down frame, jaw angle), PSM2 (same 7), object position, object − tip1, object − tip2, the object's
two key points with their Euler angles (3 + 3 each). A pitch-mode arm's tilt is its "roll" term.
Info adds ``tip_position`` (2, 3) and ``jaw_angle`` (2,) for the metrics and the recorder.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from surrol_data.envs import kinematics as kin
from surrol_data.envs import objects, physics
from surrol_data.envs.adaptive_steps import SubstepPlanner
from surrol_data.envs.ecm import SceneEndoscope
from surrol_data.envs.grasp import Grasp
from surrol_data.envs.numeric import clip
from surrol_data.envs.psm import Psm
from surrol_data.envs.psm_env import (ACTION_PITCH_RAD, PITCH_LIMIT_RAD, PSM1_BASE_YAW_RAD, PSM1_RCM,  # noqa: F401
                                      PSM2_BASE_YAW_RAD, ROTATION_MODES,  # noqa: F401
                                      PsmEnv, approach_direction, tilted_tool, tip_clip_box,
                                      tip_orientation_features, tool_down, wrap_angle)
from surrol_data.envs.units import ACTION_POSITION_M, ACTION_YAW_RAD, SCALING

# PSM2 mirrors PSM1 across the table's centre line (reference RCM points (0.507, ±0.0736, 0.8524) m).
PSM2_RCM = PSM1_RCM * np.array([1.0, -1.0, 1.0])


@dataclass(frozen=True)
class ArmStart:
    """Where an arm starts an episode: tip position (m), rotation angle (yaw or pitch, rad), jaw angle (rad)."""
    tip: np.ndarray
    angle: float
    jaw: float


class BimanualEnv(PsmEnv):
    ACTION_DIM = 10
    OBSERVATION_DIM = 35
    ROTATION_MODE = ("yaw", "yaw")          # per arm, "yaw" or "pitch"
    # Per-arm tip workspaces (real metres, rows x/y/z as [low, high]); commands are clipped to tip_clip_box of them.
    WORKSPACES = (np.array([[0.50, 0.60], [0.0, 0.05], [0.675, 0.745]]),
                  np.array([[0.50, 0.60], [-0.05, 0.0], [0.675, 0.745]]))
    HELD_AT_START: int | None = None        # index of the arm that holds the object when an episode starts
    OBJECT_TRAVEL_PER_STEP_M = physics.MAX_OBJECT_TRAVEL_PER_STEP_M   # the adaptive sub-steps' limit (physics.py)
    ORACLE_GAIN = 0.5

    def __init__(self, render_mode: str | None = None, **kwargs):
        for mode in self.ROTATION_MODE:
            if mode not in ROTATION_MODES:
                raise ValueError(f"{type(self).__name__}.ROTATION_MODE entries must be one of {ROTATION_MODES}, "
                                 f"got {mode!r}")
        super().__init__(render_mode=render_mode, **kwargs)
        self._tips = [np.eye(4), np.eye(4)]
        self._target_boxes = [tuple(np.ascontiguousarray(side) for side in tip_clip_box(ws).T)
                              for ws in self.WORKSPACES]

    # ------------------------------------------------------------------ to be declared by tasks
    def reset_task(self, rng: np.random.Generator) -> tuple[ArmStart, ArmStart]:
        """Place objects (without simulating); return where both arms start. If ``HELD_AT_START`` names an
        arm, the object must already sit between that arm's jaws at the returned pose and jaw angle."""
        raise NotImplementedError

    def object_state(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """(object position, (key point 1, its Euler xyz), (key point 2, its Euler xyz)), metres / rad."""
        raise NotImplementedError

    def settle_objects(self) -> None:
        """After the settling steps of a reset: e.g. let resting bodies sleep until something touches them."""

    @property
    def psm(self) -> Psm:
        """PSM1, for code that names a single arm (each arm is in ``psms``)."""
        return self.psms[0]

    # ------------------------------------------------------------------ scene
    def _build_world(self) -> None:
        objects.make_table(self.client, visual=self.visual)
        self.psms = (Psm(self.client, PSM1_RCM, PSM1_BASE_YAW_RAD, visual=self.visual),
                     Psm(self.client, PSM2_RCM, PSM2_BASE_YAW_RAD, visual=self.visual))
        # A shaft does not collide with the other arm: at the oracles' hand-overs the tools meet tip to tip over
        # the block or needle, and the 8 mm shafts, converging from the two RCMs, would touch the other tool's
        # shaft and wrist and jam it (a limit of those plans more than of the arms). Each shaft still collides
        # with the scene and the objects; the two wrists and jaw pairs still collide with each other.
        a, b = self.psms[0].body, self.psms[1].body
        for link in range(self.client.getNumJoints(a)):
            self.client.setCollisionFilterPair(a, b, 3, link, 0)
            self.client.setCollisionFilterPair(a, b, link, 3, 0)
        self.object_id = -1
        self.build_scene()
        self.goal_marker = objects.make_goal_marker(self.client, visual=self.visual)
        # Held objects do not collide with the holding jaws (see Grasp); the world is rebuilt every episode.
        self.grasps = tuple(Grasp(self.client, psm, self.object_id, self.grasp_lift_condition) for psm in self.psms)
        for grasp in self.grasps:   # each hand knows the other's, for the hand-over (one constraint at a time)
            grasp.peers = tuple(g for g in self.grasps if g is not grasp)
        self._substeps = SubstepPlanner(self.client, self.grasps, self.dynamic_bodies,
                                        object_travel_m=self.OBJECT_TRAVEL_PER_STEP_M)

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        gym.Env.reset(self, seed=seed)
        # A whole new world every episode. Fresh bodies (PsmEnv's way) are not enough here: while both arms
        # hold the object, the solver's order over the two grasp constraints and the contacts depends on what
        # earlier episodes left in PyBullet's tables (an episode that ended with a dropped needle moved the next
        # hand-over by ~1 mm), and equal seeds must give equal episodes bit for bit. It costs ~3 ms.
        self.client.resetSimulation()
        physics.configure(self.client)
        self._constraint_erp = physics.DEFAULT_CONSTRAINT_ERP
        self._build_world()
        if self.endoscope is not None:   # the camera=True option's still ECM went with the old world
            self.endoscope = SceneEndoscope(self.client, self.endoscope.size, scene_scale=SCALING,
                                            camera=self.endoscope.camera)
        starts = self.reset_task(self.np_random)
        for i, (psm, start) in enumerate(zip(self.psms, starts)):
            pose = kin.pose_from(start.tip, self._tool_rotation(i, start.angle))
            sol = psm.ik(pose)
            if not sol.within_limits:
                raise RuntimeError(f"PSM{i + 1}'s initial tip pose (at {start.tip}) is outside its reach; "
                                   "check the task's workspace and start angles")
            psm.reset_joints(sol.q, start.jaw)
        if self.HELD_AT_START is not None:
            # The object was placed in the hand by reset_task: fix it there and squeeze, as after a grasp.
            self.psms[self.HELD_AT_START].command_jaw(physics.JAW_CLOSED_RAD)
            self.grasps[self.HELD_AT_START].attach()
        self.simulate(physics.SETTLE_STEPS)
        self.settle_objects()
        return self._start_episode()

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        if action.size != self.ACTION_DIM:
            raise ValueError(f"{type(self).__name__} takes a {self.ACTION_DIM}-D action [PSM1 5 | PSM2 5], "
                             f"got shape {action.shape}")
        action = clip(action.reshape(2, 5), -1.0, 1.0)
        for i in range(2):
            self._apply_arm_action(i, action[i])
        self._closing = tuple(g for g, arm_action in zip(self.grasps, action) if arm_action[4] < 0)
        self.simulate(physics.SUBSTEPS)
        self._closing = ()
        for grasp, arm_action in zip(self.grasps, action):
            grasp.update(closing=arm_action[4] < 0)
        obs = self._get_obs()
        info = self._info(obs)
        return obs, self._step_reward(obs, info), False, False, info

    # ------------------------------------------------------------------ internals
    def simulate(self, steps: int) -> None:
        self._step_physics(steps, self._closing)
        self._tips = [psm.tip_pose() for psm in self.psms]

    def tip_pose(self, arm: int = 0) -> np.ndarray:
        return self._tips[arm]

    def _tool_rotation(self, arm: int, angle: float) -> np.ndarray:
        return tilted_tool(angle) if self.ROTATION_MODE[arm] == "pitch" else tool_down(angle)

    def _rotation_angle(self, arm: int, pose: np.ndarray) -> float:
        """The arm's controlled angle at tip ``pose``: the tilt (roll term) in pitch mode, the yaw in yaw mode."""
        features = self._orientation_features(pose)
        return float(features[0] if self.ROTATION_MODE[arm] == "pitch" else features[2])

    def _apply_arm_action(self, arm: int, action: np.ndarray) -> None:
        pose = self._tips[arm]
        target = pose[:3, 3] + action[:3] * ACTION_POSITION_M
        target = clip(target, *self._target_boxes[arm])
        angle = self._rotation_angle(arm, pose)
        if self.ROTATION_MODE[arm] == "pitch":
            angle = float(min(max(angle + action[3] * ACTION_PITCH_RAD, -PITCH_LIMIT_RAD), PITCH_LIMIT_RAD))
        else:
            angle = angle + action[3] * ACTION_YAW_RAD
        psm = self.psms[arm]
        psm.command_tip(kin.pose_from(target, self._tool_rotation(arm, angle)), ramp=True)
        psm.command_jaw(physics.JAW_CLOSED_RAD if action[4] < 0 else physics.JAW_OPEN_RAD)

    def robot_state(self) -> np.ndarray:
        return np.concatenate([
            np.concatenate([pose[:3, 3], self._orientation_features(pose), [psm.jaw_angle()]])
            for pose, psm in zip(self._tips, self.psms)])

    def observation_vector(self) -> np.ndarray:
        robot = self.robot_state()
        pos, (p1, e1), (p2, e2) = self.object_state()
        return np.concatenate([robot, pos, pos - robot[0:3], pos - robot[7:10], p1, e1, p2, e2])

    def _info(self, obs: dict) -> dict:
        state = obs["observation"]
        return {"is_success": float(self.is_success(obs["achieved_goal"], obs["desired_goal"])),
                "tip_position": np.stack([state[0:3], state[7:10]]).astype(np.float32),
                "jaw_angle": np.array([state[6], state[13]], dtype=np.float32),
                "grasped": np.array([g.attached for g in self.grasps]),
                "drops": sum(g.drops for g in self.grasps)}

    # ------------------------------------------------------------------ oracle
    @property
    def oracle_waypoints(self) -> list[dict]:
        """The oracle's plan for this episode (made at reset). Each waypoint is ``{"arms": (PSM1 step,
        PSM2 step), "hold": steps}``; an arm step has ``target`` (tip position in metres, or a callable of the
        observation), ``angle`` (its yaw or pitch, see ``ROTATION_MODE``), ``jaw`` and tolerances ``tol`` (m)
        and ``angle_tol`` (rad). A waypoint is done when both arms are within tolerance for ``hold`` steps."""
        return list(self._waypoints)

    def _waypoint_action(self, wp: dict, obs: dict) -> tuple[np.ndarray, bool]:
        """Both arms at once (the oracle loop is PsmEnv's): each tip moves towards its target at most ``gain``
        cm per axis per step and turns towards its angle; the waypoint is reached when both arms are."""
        state = np.asarray(obs["observation"], dtype=np.float64)
        actions, reached = [], True
        for arm, step in enumerate(wp["arms"]):
            action, arm_reached = self._arm_oracle_action(arm, step, state, obs)
            actions.append(action)
            reached = reached and arm_reached
        return np.concatenate(actions).astype(np.float32), reached

    def _idle_action(self) -> np.ndarray:
        last = self._waypoints[-1]["arms"] if self._waypoints else ({"jaw": 0.5}, {"jaw": 0.5})
        return np.array([0, 0, 0, 0, last[0]["jaw"], 0, 0, 0, 0, last[1]["jaw"]], dtype=np.float32)

    def _arm_oracle_action(self, arm: int, step: dict, state: np.ndarray, obs: dict) -> tuple[np.ndarray, bool]:
        tip = state[7 * arm: 7 * arm + 3]
        pitch_mode = self.ROTATION_MODE[arm] == "pitch"
        angle = state[7 * arm + (3 if pitch_mode else 5)]
        target = step["target"](obs) if callable(step["target"]) else step["target"]
        err = np.asarray(target, dtype=np.float64) - tip
        angle_err = float(wrap_angle(step.get("angle", angle) - angle))
        reached = np.linalg.norm(err) < step.get("tol", 1e-3) and abs(angle_err) < step.get("angle_tol", 0.05)
        delta = err / ACTION_POSITION_M
        delta = delta / max(1.0, np.abs(delta).max()) * step.get("gain", self.ORACLE_GAIN)
        unit = ACTION_PITCH_RAD if pitch_mode else ACTION_YAW_RAD
        d_angle = np.clip(angle_err / unit, -0.5, 0.5)
        return np.array([*delta, d_angle, step["jaw"]]), reached

"""What the simulated operator sees of a task: one arm's tool, its object and its steps of the plan.

The operator model (:mod:`.operator`) reasons about one tool: a tip position, one rotation angle, a jaw, the
object it handles, and a list of steps (tip target, angle, jaw). A view turns each kind of task into that:

* :class:`PsmView` — a single-PSM task is already that (its observation layout is the model's);
* :class:`ArmView` — one arm of a bimanual task: that arm's terms of the 35-D observation and its half of
  each two-arm waypoint; the two hands of one person share the plan's steps (see ``Team`` in the operator);
* :class:`CameraView` — an ECM task: the "tool" is the camera, and its one step is to null the task's
  ``action_error`` (what the image shows still has to change, in action units) — the person watches the
  screen and moves the camera until the target looks right.

Every view presents the observation in the single-PSM layout (tip 0:3, angle at 5, jaw 6, object point
13:16, object yaw 18) and keeps the raw observation under ``"raw"`` for the plan's closed-loop targets.
"""

from __future__ import annotations

import numpy as np

from surrol_data.collect.mapping import MappingSettings
from surrol_data.envs.units import ACTION_POSITION_M, ACTION_YAW_RAD, CONTROL_PERIOD_S


LOOSE_TOL_M = 0.5        # a plan step this tolerant only says where to head, not how precisely
SNAPSHOT_TOL_M = 0.003


class PsmView:
    """A single-PSM task (``PsmEnv``): the observation and the plan as they are."""

    kind = "psm"

    def __init__(self, env):
        self.env = env
        self.has_object = bool(env.OBJECT_OBS)
        self.uses_jaw = not env.BLOCK_JAW
        self.controls_angle = not env.FIXED_YAW
        from surrol_data.envs.psm_env import ACTION_PITCH_RAD

        self.pitch = env.ROTATION_MODE == "pitch"
        self.position_unit_m = ACTION_POSITION_M   # tool motion of one action unit
        self.angle_unit_rad = ACTION_PITCH_RAD if self.pitch else ACTION_YAW_RAD   # tool rotation of one unit
        self.angle_ratio = self.angle_unit_rad / ACTION_YAW_RAD   # ... relative to the mapping's assumption
        self.control_period_s = CONTROL_PERIOD_S
        self.angle_is_goal = False               # the task's success is the angle itself (ECM roll)

    def mapping(self, settings: MappingSettings) -> MappingSettings:
        """The mapping the operator's internal model inverts (the one that reaches this tool)."""
        return settings

    def episode_marker(self):
        plan = self.env.oracle_waypoints
        return plan[0] if plan else self.env.goal

    def plan(self) -> list[dict]:
        return self.env.oracle_waypoints

    def observation(self, obs: dict) -> dict:
        if not self.pitch:
            return obs
        state = np.array(obs["observation"], np.float64)
        state[5] = state[3]           # the controlled angle (tilt) where the model reads it
        return {**obs, "observation": state}

    def info(self, info: dict) -> dict:
        return info

    def holds_at_start(self, info: dict) -> bool:
        return False


def _layout(tip, angle, jaw, obj, point, obj_yaw, raw, achieved, desired) -> dict:
    state = np.zeros(19)
    state[0:3], state[5], state[6] = tip, angle, jaw
    state[7:10], state[10:13], state[13:16], state[18] = obj, obj - tip, point, obj_yaw
    return {"observation": state, "achieved_goal": np.asarray(achieved, np.float64),
            "desired_goal": np.asarray(desired, np.float64), "raw": raw}


def _raw_target(target):
    """A plan target written for the raw observation, callable on a view observation."""
    return (lambda view_obs: target(view_obs["raw"])) if callable(target) else target


class ArmView(PsmView):
    """Arm ``arm`` of a bimanual task (``BimanualEnv``); a pitch-mode arm's controlled angle is its tilt."""

    kind = "bimanual-arm"

    def __init__(self, env, arm: int):
        from surrol_data.envs.psm_env import ACTION_PITCH_RAD

        if arm not in (0, 1):
            raise ValueError(f"arm must be 0 (PSM1) or 1 (PSM2) in a bimanual task, got {arm}")
        self.env, self.arm = env, arm
        self.has_object, self.uses_jaw, self.controls_angle = True, True, True
        self.pitch = env.ROTATION_MODE[arm] == "pitch"
        self.position_unit_m = ACTION_POSITION_M
        self.angle_unit_rad = ACTION_PITCH_RAD if self.pitch else ACTION_YAW_RAD
        self.angle_ratio = self.angle_unit_rad / ACTION_YAW_RAD
        self.control_period_s = CONTROL_PERIOD_S
        self.angle_is_goal = False

    def plan(self) -> list[dict]:
        steps = []
        for wp in self.env.oracle_waypoints:
            s = wp["arms"][self.arm]
            step = {"target": _raw_target(s["target"]), "jaw": s["jaw"], "tol": s.get("tol", 1e-3),
                    "yaw_tol": s.get("angle_tol", 0.05)}
            if callable(s["target"]) and step["tol"] >= LOOSE_TOL_M:
                # "Go roughly there while the other hand works" (e.g. back off 1 cm): the oracle keeps moving
                # towards such a target; a person makes the move once, to where it pointed when the step began.
                step.update(snapshot=True, tol=SNAPSHOT_TOL_M)
            if "angle" in s:
                step["yaw"] = s["angle"]
            steps.append(step)
        return steps

    def observation(self, obs: dict) -> dict:
        o = np.asarray(obs["observation"], np.float64)
        a = 7 * self.arm
        tip, angle, jaw = o[a:a + 3], o[a + (3 if self.pitch else 5)], o[a + 6]
        # The object's centre stands for the grasp point (a failed grasp re-aims at where the object now is).
        return _layout(tip, angle, jaw, o[14:17], o[14:17], o[28], obs, obs["achieved_goal"], obs["desired_goal"])

    def info(self, info: dict) -> dict:
        return {**info, "grasped": bool(np.asarray(info.get("grasped", False)).reshape(-1)[self.arm])}

    def holds_at_start(self, info: dict) -> bool:
        return self.info(info)["grasped"]


class CameraView(PsmView):
    """An ECM task (``EcmEnv``): the tool is the camera; the one step nulls the task's ``action_error``.

    The view's tip is minus the position part of the error (metres of camera motion) and its target the origin;
    its angle is minus the rotation part (rad of camera roll), target 0. The operator's internal mapping is the
    session's camera mapping: camera motion = device motion × ``camera_motion_scale``.
    """

    kind = "camera"

    def __init__(self, env):
        self.env = env
        self.has_object, self.uses_jaw = False, False
        self.controls_angle = env.ACTION_DIM in (1, 4)
        self.position_unit_m = getattr(env, "ACTION_TRANSLATION_M", ACTION_POSITION_M)
        self.angle_unit_rad = getattr(env, "ACTION_ROTATION_RAD", ACTION_YAW_RAD)
        self.angle_ratio = 1.0      # the session maps a hand roll to camera roll at the rotation scale
        self.angle_is_goal = self.controls_angle
        from surrol_data.envs.physics import ECM_CONTROL_PERIOD_S

        self.control_period_s = ECM_CONTROL_PERIOD_S

    def mapping(self, settings: MappingSettings) -> MappingSettings:
        from dataclasses import replace

        return replace(settings, motion_scale=settings.camera_motion_scale)

    def episode_marker(self):
        return self.env.goal

    def plan(self) -> list[dict]:
        step = {"target": np.zeros(3), "jaw": 1.0, "tol": 1e-3, "yaw_tol": 0.01}
        if self.controls_angle:
            step["yaw"] = 0.0
        return [step]

    def observation(self, obs: dict) -> dict:
        err = np.asarray(self.env.action_error(obs), np.float64)
        tip = -err[:3] * self.position_unit_m
        angle = -err[3] * self.angle_unit_rad
        zero = np.zeros(3)
        return _layout(tip, angle, 0.0, zero, zero, 0.0, obs, obs["achieved_goal"], obs["desired_goal"])

    def info(self, info: dict) -> dict:
        return {**info, "grasped": False}


def task_view(env, arm: int = 0):
    """The view of ``env`` (unwrapped) that the operator of arm ``arm`` works with."""
    from surrol_data.envs.bimanual_env import BimanualEnv
    from surrol_data.envs.ecm_env import EcmEnv
    from surrol_data.envs.psm_env import PsmEnv

    if isinstance(env, BimanualEnv):
        return ArmView(env, arm)
    if arm != 0:
        raise ValueError(f"arm={arm}: {type(env).__name__} has only one arm (arm 0)")
    if isinstance(env, PsmEnv):
        return PsmView(env)
    if isinstance(env, EcmEnv):
        if not hasattr(env, "action_error"):
            raise ValueError(f"{type(env).__name__} declares no action_error(obs): the simulated operator cannot "
                             "tell what to aim for in it")
        return CameraView(env)
    raise ValueError(f"the simulated operator drives PSM, bimanual and ECM tasks; {type(env).__name__} is none")

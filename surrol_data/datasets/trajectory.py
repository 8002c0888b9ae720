"""One episode in memory: what a collector or a policy rollout produced, before or after it is on disk.

Shapes (T = number of actions taken):

* ``observation`` (T+1, obs_dim), ``achieved_goal`` (T+1, goal_dim), ``desired_goal`` (T+1, goal_dim):
  float32, the reset observation first. Units as in :mod:`surrol_data.envs.units`.
* ``action`` (T, act_dim) float32 in [-1, 1]; ``reward`` (T,) float32; ``success`` (T,) bool (the
  ``info["is_success"]`` after each action); ``terminated`` (T,) bool.
* ``tip_position`` (T+1, n_arms, 3) float32: tool-tip positions in metres (world frame) — what the
  proficiency metrics measure. ``jaw_angle`` (T+1, n_arms) float32, radians.
* ``flags``: per-step device flags, name -> (T,) bool, e.g. ``clutch``, ``jaw_button``. Every trajectory
  carries the same two names so datasets of different sources merge. Where the env reports grasps (PSM tasks)
  the :data:`EVENT_FLAGS` join them: ``grasped`` (T, n_arms) and ``drop`` (T,).
* ``images``: optional camera name -> (T+1, H, W, 3) uint8.
* ``policy_action``: optional (T, act_dim) float32, in an intervention session (``collect --source intervene``)
  the action the policy proposed at each step, beside ``action``, what was executed; the session's flag
  :data:`INTERVENTION` ``intervention`` (T, n_arms) says which arms the operator drove at each step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DEVICE_FLAGS = ("clutch", "jaw_button")
# An env made with ``camera=True`` adds the endoscope view as ``obs["image"]``; episodes record it as this camera
# (the dataset feature ``observation.images.endoscope``).
ENV_CAMERA = "endoscope"
# Env events after each action, from the step's info where the env reports grasps: ``grasped`` (T, n_arms) — the
# arm holds the object; ``drop`` (T,) — a hold was lost while the jaw stayed closed (the env's drop count rose).
# The proficiency metrics count failed grasps and drops from them; without them those counts are unknown (nan).
EVENT_FLAGS = ("grasped", "drop")
# Who acted, in an intervention session: ``intervention`` (T, n_arms) — the operator held the takeover control of
# that arm, and the executed action of the arm is the operator's, not the policy's.
INTERVENTION = "intervention"


@dataclass
class Trajectory:
    observation: np.ndarray
    achieved_goal: np.ndarray
    desired_goal: np.ndarray
    action: np.ndarray
    reward: np.ndarray
    success: np.ndarray
    terminated: np.ndarray
    tip_position: np.ndarray
    jaw_angle: np.ndarray
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    images: dict[str, np.ndarray] = field(default_factory=dict)
    policy_action: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.action)
        for name in ("observation", "achieved_goal", "desired_goal", "tip_position", "jaw_angle"):
            if len(getattr(self, name)) != n + 1:
                raise ValueError(f"Trajectory.{name} has {len(getattr(self, name))} rows, expected T+1 = {n + 1}")
        for name in ("reward", "success", "terminated"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"Trajectory.{name} has {len(getattr(self, name))} rows, expected T = {n}")
        for flag in DEVICE_FLAGS:
            self.flags.setdefault(flag, np.zeros(n, dtype=bool))
        for name, values in self.flags.items():
            if len(values) != n:
                raise ValueError(f"Trajectory.flags[{name!r}] has {len(values)} rows, expected T = {n}")
        if (self.policy_action is None) != (INTERVENTION not in self.flags):
            raise ValueError("Trajectory.policy_action and flags['intervention'] come together (an intervention "
                             "session records both) or not at all")
        if self.policy_action is not None and np.shape(self.policy_action) != np.shape(self.action):
            raise ValueError(f"Trajectory.policy_action has shape {np.shape(self.policy_action)}, the actions "
                             f"{np.shape(self.action)}")

    def __len__(self) -> int:
        return len(self.action)

    @property
    def is_success(self) -> bool:
        """Success at any step (the collectors' keep rule and the 'any-time' convention)."""
        return bool(np.any(self.success))

    @property
    def final_success(self) -> bool:
        """Success at the last step (DEX/baselines convention for evaluation)."""
        return bool(self.success[-1]) if len(self.success) else False


class TrajectoryBuilder:
    """Accumulates one step at a time and returns a :class:`Trajectory`."""

    def __init__(self, obs: dict, tip_position: np.ndarray, jaw_angle: np.ndarray, image: dict | None = None):
        obs, image = _split_image(obs, image)
        self._obs = {k: [np.asarray(v, np.float32)] for k, v in obs.items()}
        self._tip = [np.asarray(tip_position, np.float32).reshape(-1, 3)]
        self._jaw = [np.asarray(jaw_angle, np.float32).reshape(-1)]
        self._images = {k: [v] for k, v in (image or {}).items()}
        self._action: list[np.ndarray] = []
        self._reward: list[float] = []
        self._success: list[bool] = []
        self._terminated: list[bool] = []
        self._flags: dict[str, list[bool]] = {f: [] for f in DEVICE_FLAGS}
        self._events: list[tuple[np.ndarray, bool]] = []
        self._drops = 0   # the env's drop count (0 after a reset)
        self._intervention: list[np.ndarray] = []
        self._policy_action: list[np.ndarray] = []

    def add(self, action, obs: dict, reward: float, success: bool, terminated: bool,
            tip_position, jaw_angle, flags: dict | None = None, image: dict | None = None,
            info: dict | None = None, intervention=None, policy_action=None) -> None:
        """One step. ``info``: the step's info dict; its ``grasped`` and ``drops`` become the :data:`EVENT_FLAGS`
        (pass it at every step or at none). ``intervention`` (n_arms bools: the operator drove the arm) and
        ``policy_action`` (what the policy proposed) in an intervention session: at every step or at none."""
        obs, image = _split_image(obs, image)
        self._action.append(np.asarray(action, np.float32))
        for k, v in obs.items():
            self._obs[k].append(np.asarray(v, np.float32))
        self._reward.append(float(reward))
        self._success.append(bool(success))
        self._terminated.append(bool(terminated))
        self._tip.append(np.asarray(tip_position, np.float32).reshape(-1, 3))
        self._jaw.append(np.asarray(jaw_angle, np.float32).reshape(-1))
        flags = flags or {}
        for name in self._flags:
            self._flags[name].append(bool(flags.get(name, False)))
        for k, v in (image or {}).items():
            self._images[k].append(v)
        if info is not None and "grasped" in info:
            drops = int(np.sum(info.get("drops", 0)))
            self._events.append((np.atleast_1d(np.asarray(info["grasped"], bool)), drops > self._drops))
            self._drops = drops
        if intervention is not None:
            self._intervention.append(np.atleast_1d(np.asarray(intervention, bool)))
            self._policy_action.append(np.asarray(policy_action, np.float32))

    def __len__(self) -> int:
        return len(self._action)

    def build(self) -> Trajectory:
        flags = {k: np.asarray(v, bool) for k, v in self._flags.items()}
        if self._events and len(self._events) == len(self._action):
            flags["grasped"] = np.stack([g for g, _ in self._events])
            flags["drop"] = np.array([d for _, d in self._events], bool)
        policy_action = None
        if self._intervention:
            if len(self._intervention) != len(self._action):
                raise ValueError(f"TrajectoryBuilder: intervention given at {len(self._intervention)} of "
                                 f"{len(self._action)} steps; give it at every step or at none")
            flags[INTERVENTION] = np.stack(self._intervention)
            policy_action = np.stack(self._policy_action).reshape(len(self._action), -1)
        return Trajectory(
            observation=np.stack(self._obs["observation"]),
            achieved_goal=np.stack(self._obs["achieved_goal"]),
            desired_goal=np.stack(self._obs["desired_goal"]),
            action=np.asarray(self._action, np.float32).reshape(len(self._action), -1),
            reward=np.asarray(self._reward, np.float32),
            success=np.asarray(self._success, bool),
            terminated=np.asarray(self._terminated, bool),
            tip_position=np.stack(self._tip),
            jaw_angle=np.stack(self._jaw),
            flags=flags,
            images={k: np.stack(v) for k, v in self._images.items()},
            policy_action=policy_action,
        )


def _split_image(obs: dict, image: dict | None) -> tuple[dict, dict | None]:
    """The env's ``obs["image"]`` (camera=True) becomes the :data:`ENV_CAMERA` image, not a float observation."""
    if "image" not in obs:
        return obs, image
    rest = {k: v for k, v in obs.items() if k != "image"}
    return rest, {ENV_CAMERA: np.asarray(obs["image"], np.uint8), **(image or {})}

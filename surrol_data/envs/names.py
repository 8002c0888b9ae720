"""What every dimension of a task's observation, goals and action means, and which arms it moves.

Datasets store these names with each vector (LeRobot's ``names``), so a plot, a policy config or a person
reading ``meta/info.json`` sees ``needle_x`` where a bare vector would say ``s7``. The layouts are the ones
the env bases build (:meth:`PsmEnv.observation_vector`, :meth:`BimanualEnv.observation_vector`, the ECM
tasks' ``observe``); ``tests/test_names.py`` checks every registered task against its spaces.

``robot_type`` names the arms a task moves, as LeRobot's ``info.json`` records it: ``dvrk_psm`` (one PSM),
``dvrk_psm_x2`` (two PSMs), ``dvrk_ecm`` (the endoscope arm).
"""

from __future__ import annotations

from dataclasses import dataclass

_XYZ = ("x", "y", "z")
_RPY = ("roll", "pitch", "yaw")
_PSM_ROBOT = (*(f"tip_{c}" for c in _XYZ), *(f"tip_{a}" for a in _RPY), "jaw")
_PSM_ACTION = ("dx", "dy", "dz", "dyaw", "jaw")


def is_ecm_action(action_dim: int) -> bool:
    """Whether an action of this size moves the endoscope (a 1-, 3- or 4-D camera action) rather than PSMs
    (5 dimensions per arm): what collectors and the GUI ask before they have the env's class at hand."""
    return action_dim % len(_PSM_ACTION) != 0


def _xyz(prefix: str) -> tuple[str, ...]:
    return tuple(f"{prefix}_{c}" for c in _XYZ)


def _rpy(prefix: str) -> tuple[str, ...]:
    return tuple(f"{prefix}_{a}" for a in _RPY)


# Task -> (the object its observation describes, what its achieved goal measures). ``None``: no object terms.
_PSM_TASKS = {
    "NeedleReach": (None, "tip"),
    "NeedlePick": ("needle", "needle_waypoint"),
    "GauzeRetrieve": ("gauze", "gauze"),
    "PegTransfer": ("block", "block"),
    "NeedleRegrasp": ("needle", "needle_keypoint1"),
    "BiPegTransfer": ("block", "block"),
    "PickAndPlace": ("jack", "jack"),          # the object terms describe the jack being placed
    "MatchBoard": ("block", "block"),
    "MatchBoardPanel": ("block", "block"),
    "PegBoard": ("ring", "ring"),
    "NeedleRings": ("needle", "needle_tip"),
}
# Tasks whose goals are more than one point, or whose observation appends terms to the base layout:
# task -> (achieved goal names, desired goal names, state terms after the base layout).
_GOAL_TERMS = {
    "PickAndPlace": ((*_xyz("red_jack"), *_xyz("green_jack")), (*_xyz("red_tray"), *_xyz("green_tray")),
                     (*_xyz("red_jack"), *_xyz("green_jack"))),
    "MatchBoardPanel": ((*_xyz("block"), *_xyz("handle")), (*_xyz("goal_cell"), *_xyz("goal_handle")),
                        (*_xyz("handle"), "drawer_opening")),
    "NeedleRings": ((*_xyz("needle_tip"), "threaded"), (*_xyz("goal"), "goal_threaded"), ()),
}


@dataclass(frozen=True)
class DimensionNames:
    state: tuple[str, ...]
    achieved_goal: tuple[str, ...]
    desired_goal: tuple[str, ...]
    action: tuple[str, ...]
    robot_type: str
    n_arms: int  # arms whose tip and jaw the datasets record (1 for the ECM: its camera tip)


def _psm(task: str, bimanual: bool) -> DimensionNames:
    obj, achieved = _PSM_TASKS[task]
    arms = ("psm1_", "psm2_") if bimanual else ("",)
    robot = tuple(p + n for p in arms for n in _PSM_ROBOT)
    if obj is None:
        state = robot
    elif bimanual:
        state = (*robot, *_xyz(obj), *_xyz(f"{obj}_from_psm1_tip"), *_xyz(f"{obj}_from_psm2_tip"),
                 *_xyz("keypoint1"), *_rpy("keypoint1"), *_xyz("keypoint2"), *_rpy("keypoint2"))
    else:
        state = (*robot, *_xyz(obj), *_xyz(f"{obj}_from_tip"), *_xyz(f"{obj}_waypoint"), *_rpy(obj))
    achieved_names, desired_names, extra = _GOAL_TERMS.get(task, (_xyz(achieved), _xyz("goal"), ()))
    return DimensionNames(state=(*state, *extra), achieved_goal=achieved_names, desired_goal=desired_names,
                          action=tuple(p + n for p in arms for n in _PSM_ACTION),
                          robot_type="dvrk_psm_x2" if bimanual else "dvrk_psm", n_arms=len(arms))


_ECM_POSE = (*_xyz("eef"), *_rpy("eef"))  # end effector in the RCM frame
_TRACK = (*_ECM_POSE, "target_in_view", "target_image_x", "target_image_y", "wz")
_ECM_TASKS = {
    "ECMReach": (_ECM_POSE, _xyz("eef_world"), _xyz("goal"), _xyz("d")),
    "MisOrient": ((*_ECM_POSE, *_rpy("camera_world")), ("misorientation",), ("goal_misorientation",), ("droll",)),
    "StaticTrack": (_TRACK, ("target_image_x", "target_image_y", "wz"),
                    ("goal_image_x", "goal_image_y", "goal_wz"), ("v_right", "v_down", "v_forward")),
}
_ECM_TASKS["ActiveTrack"] = _ECM_TASKS["StaticTrack"]


def dimension_names(env) -> DimensionNames:
    """Names of ``env``'s observation / goal / action dimensions and its ``robot_type`` (``env`` may be wrapped)."""
    from surrol_data.envs.bimanual_env import BimanualEnv
    from surrol_data.envs.ecm_env import EcmEnv

    base = getattr(env, "unwrapped", env)
    task = next((cls.__name__ for cls in type(base).__mro__ if cls.__name__ in {*_PSM_TASKS, *_ECM_TASKS}), None)
    if task is None:
        raise ValueError(f"{type(base).__name__} is not a surrol_data task with named dimensions; add it to "
                         "surrol_data.envs.names")
    if isinstance(base, EcmEnv):
        state, achieved, desired, action = _ECM_TASKS[task]
        return DimensionNames(state, achieved, desired, action, robot_type="dvrk_ecm", n_arms=1)
    return _psm(task, bimanual=isinstance(base, BimanualEnv))

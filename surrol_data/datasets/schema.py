"""The on-disk contract of a surrol_data dataset, in one place.

A dataset is a LeRobot v3 dataset (written by the real ``lerobot`` package) with

* **per-frame features** from :func:`frame_features`: frame ``t`` holds the observation ``s_t``, the action
  ``a_t``, the reward/done/success that followed it, and ``s_{t+1}`` under ``next.observation.*`` so a
  reader rebuilds every transition, the last one included, without peeking into the next row;
* **per-episode provenance**: the :data:`PROVENANCE_COLUMNS`, stored as extra columns
  ``provenance/<name>`` of ``meta/episodes/*.parquet`` (so LeRobot's ``episode_filter`` sees them);
* a sidecar ``meta/surrol_data.json`` with dataset-level facts (:data:`SCHEMA_VERSION`, task, env id ...).

Mapping from a :class:`~surrol_data.datasets.trajectory.Trajectory` (T actions) to frames ``t = 0..T-1``:

=========================================  =====================================================
``observation.state``                       ``observation[t]``, each dimension named by the env
                                            (:func:`surrol_data.envs.names.dimension_names`)
``observation.environment_state``           ``achieved_goal[t]`` then ``desired_goal[t]``: the object
                                            and goal state, the key LeRobot policies (ACT, Diffusion)
                                            read as the environment state
``next.observation.*``                      the same at ``t+1``
``action``, ``next.reward``, ``next.success``   ``action[t]``, ``reward[t]``, ``success[t]``
``next.done``                               ``terminated[t]`` — the MDP ended (don't bootstrap)
``next.truncated``                          the episode ended at ``t`` without terminating (time
                                            limit, operator stop): true on that last frame only
``complementary_info.tip_position``         ``tip_position[t]`` flattened (n_arms*3), metres
``complementary_info.jaw_angle``            ``jaw_angle[t]``, radians
``complementary_info.next_tip_position``,   the same after the action (row ``t+1``), so the
``complementary_info.next_jaw_angle``       proficiency metrics see the whole path
``complementary_info.clutch`` / ``jaw_button``  device flags ``flags[...][t]``
``complementary_info.grasped`` / ``drop``   env events ``flags[...][t]`` (:func:`event_features`; datasets of
                                            tasks with grasps, recorded since they were added)
``complementary_info.is_intervention``      who acted (:func:`intervention_features`, intervention sessions
                                            only): 1.0 where the operator drove (any arm), 0.0 where the
                                            policy did — LeRobot's HIL-SERL key, float32 (1,) as its
                                            replay buffer writes it; ``intervention_arms`` per arm (bool);
``complementary_info.policy_action``        ``policy_action[t]``: what the policy proposed (``action`` is
                                            what was executed)
``observation.images.<camera>`` (video)     ``images[camera][t]`` (the image of ``s_T`` is not stored)
=========================================  =====================================================

Every dimension of every feature is named. Schema 1 (``SCHEMA_VERSION`` before 2) stored the goals as
``observation.achieved_goal`` / ``observation.desired_goal``, had no ``next.truncated`` and named the state
``s0…``; ``surrol-data upgrade DIR`` (:mod:`surrol_data.datasets.upgrade`) rewrites such a dataset.

Bookkeeping lives under ``complementary_info.*`` because LeRobot treats every ``observation.*`` key as a
policy input.
"""

from __future__ import annotations

import functools
import json
from datetime import datetime, timezone

import numpy as np

from surrol_data.datasets.trajectory import DEVICE_FLAGS

SCHEMA_VERSION = 2
# What a camera dataset's endoscope images mean, recorded in the sidecar as ``camera_version`` (a dataset with
# cameras and without the key is version 1; a dataset without cameras records none):
#   1: image up = the ECM's EEF y axis (world up at image left); PSM scenes seen from SurRoL-v2's ECM pose;
#   2: image up = the EEF x axis, as the reference renders it (world up at image up); PSM scenes framed on the
#      workspace (surrol_data.envs.ecm.PSM_SCENE_JOINTS).
# Images of two versions are not the same observation: appending and merging across versions are refused.
CAMERA_VERSION = 2
# Which renderer drew a camera dataset's images (``collect --renderer``; the envs' ``camera_renderer``), recorded in
# the sidecar as ``camera_renderer``: TinyRenderer's flat light and Panda3D's spotlit, shadowed view are not the same
# observation, so appending and merging across renderers are refused too. A camera dataset without the key was
# drawn by TinyRenderer, the envs' default and the only renderer `collect` had before the key existed.
DEFAULT_CAMERA_RENDERER = "tiny"
FPS = 5  # 1 / envs.units.CONTROL_PERIOD_S; LeRobot wants an int
PROVENANCE_PREFIX = "provenance/"
SIDECAR_PATH = "meta/surrol_data.json"
# Sidecar key of a dataset whose recorder opened it lazily and has not created the LeRobot dataset yet: its features,
# fps and robot type, from which repair() creates it (surrol_data.datasets.writer.DatasetWriter._open_lazily).
PENDING_DATASET = "pending_dataset"

# Ordered name -> python type. Every column has exactly one type and never holds None (use "", -1, nan),
# because the episodes parquet schema is fixed by the first episode and pandas/pyarrow would otherwise
# turn a column into object/null types that break filtering and appending.
PROVENANCE_COLUMNS: dict[str, type] = {
    "source": str,              # script | haptic | policy | intervention
    "device": str,              # touch | keyboard | gamepad | spacemouse | replay | simulated-operator | none
                                # | browser-keyboard | browser-gamepad (the web console)
    "operator_id": str,
    "skill": str,               # expert | novice | scripted | unknown
    "operator_simulated": bool,
    "operator_params": str,     # JSON
    "device_settings": str,     # JSON: scaling, axis map, ...
    "task": str,
    "env_id": str,
    "seed": int,
    "success": bool,
    "steps_to_success": int,    # -1 if never
    "path_length_cm": float,
    "jaw_closures": int,
    "clutch_uses": int,
    "episode_steps": int,
    "recorded_at": str,         # ISO-8601 UTC
    "duration_s": float,        # wall time of the episode, nan if unknown
    "package_version": str,
    "git_commit": str,          # "" if unknown
    "command": str,             # the command line that recorded the episode
    "content_hash": str,        # content_hash() of the episode's frames: finds duplicates and altered data
}

PROVENANCE_CHOICES: dict[str, tuple[str, ...]] = {
    "source": ("script", "haptic", "policy", "intervention"),
    "device": ("touch", "keyboard", "gamepad", "spacemouse", "replay", "simulated-operator", "browser-keyboard",
               "browser-gamepad", "none"),
    "skill": ("expert", "novice", "scripted", "unknown"),
}

# Columns the caller must state: nothing sensible can be guessed for them.
REQUIRED_PROVENANCE = ("source", "device", "skill", "task", "env_id", "seed")

# Columns derived from the trajectory by metrics.trajectory_proficiency when the caller does not give them.
METRIC_COLUMNS = ("success", "steps_to_success", "path_length_cm", "jaw_closures", "clutch_uses", "episode_steps")

_DEFAULTS: dict[str, object] = {
    "operator_id": "",
    "operator_simulated": False,
    "operator_params": "{}",
    "device_settings": "{}",
    "duration_s": float("nan"),
    "git_commit": "",
    "command": "",
    "content_hash": "",
}

_DOF_NAMES = ("dx", "dy", "dz", "dyaw", "jaw")


class ProvenanceError(ValueError):
    """A provenance dict does not follow :data:`PROVENANCE_COLUMNS`."""


class OutdatedSchemaError(ValueError):
    """The dataset was written with an earlier surrol_data schema; ``surrol-data upgrade DIR`` rewrites it."""


ENV_STATE = "observation.environment_state"
NEXT_ENV_STATE = "next.observation.environment_state"
SCHEMA1_GOAL_KEYS = ("observation.achieved_goal", "observation.desired_goal",
                     "next.observation.achieved_goal", "next.observation.desired_goal")


def _arm_prefixes(n_arms: int) -> list[str]:
    return [""] if n_arms == 1 else [f"psm{i + 1}_" for i in range(n_arms)]


def _goal_names(goal_dim: int, prefix: str) -> list[str]:
    if goal_dim == 3:
        return [f"{prefix}_{c}" for c in "xyz"]
    return [f"{prefix}_{i}" for i in range(goal_dim)]


def _action_names(act_dim: int, n_arms: int) -> list[str]:
    if act_dim == len(_DOF_NAMES) * n_arms:
        return [p + d for p in _arm_prefixes(n_arms) for d in _DOF_NAMES]
    return [f"action_{i}" for i in range(act_dim)]


def _vector(dtype: str, names: list[str]) -> dict:
    return {"dtype": dtype, "shape": (len(names),), "names": list(names)}


def _checked_names(what: str, names, dim: int) -> list[str]:
    names = [str(n) for n in names]
    if len(names) != dim:
        raise ValueError(f"frame_features: {what} has {len(names)} names, the dimension is {dim}")
    if len(set(names)) != dim:
        raise ValueError(f"frame_features: {what} names repeat: {names}")
    return names


def frame_features(obs_dim: int, goal_dim: int, act_dim: int, n_arms: int,
                   cameras: dict[str, tuple[int, int]] | None = None,
                   state_names=None, achieved_goal_names=None, desired_goal_names=None,
                   action_names=None) -> dict[str, dict]:
    """LeRobot ``features`` dict for one frame (see the module docstring for what each key holds).

    ``cameras`` maps a camera name to its (height, width); each becomes a ``video`` feature
    ``observation.images.<name>``. The ``*_names`` name each dimension; datasets recorded from an env take
    them from :func:`surrol_data.envs.names.dimension_names` (the fallbacks only number the dimensions).
    """
    for name, value in (("obs_dim", obs_dim), ("goal_dim", goal_dim), ("act_dim", act_dim), ("n_arms", n_arms)):
        if not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"frame_features: {name} must be a positive int, got {value!r}")
    state = _checked_names("state", state_names or [f"state_{i}" for i in range(obs_dim)], obs_dim)
    achieved = _checked_names("achieved goal", achieved_goal_names or _goal_names(goal_dim, "achieved"), goal_dim)
    desired = _checked_names("desired goal", desired_goal_names or _goal_names(goal_dim, "goal"), goal_dim)
    environment = _checked_names("environment state", [*achieved, *desired], 2 * goal_dim)
    action = _checked_names("action", action_names or _action_names(act_dim, n_arms), act_dim)
    arms = _arm_prefixes(n_arms)
    tip = [p + "tip_" + c for p in arms for c in "xyz"]
    jaw = [p + "jaw" for p in arms]
    features = {
        "observation.state": _vector("float32", state),
        ENV_STATE: _vector("float32", environment),
        "action": _vector("float32", action),
        "next.reward": _vector("float32", ["reward"]),
        "next.done": _vector("bool", ["done"]),
        "next.truncated": _vector("bool", ["truncated"]),
        "next.success": _vector("bool", ["success"]),
        "next.observation.state": _vector("float32", state),
        NEXT_ENV_STATE: _vector("float32", environment),
        "complementary_info.tip_position": _vector("float32", tip),
        "complementary_info.jaw_angle": _vector("float32", jaw),
        "complementary_info.next_tip_position": _vector("float32", tip),
        "complementary_info.next_jaw_angle": _vector("float32", jaw),
    }
    for flag in DEVICE_FLAGS:
        features[f"complementary_info.{flag}"] = _vector("bool", [flag])
    for cam, hw in (cameras or {}).items():
        if "/" in cam or not cam:
            raise ValueError(f"frame_features: camera name {cam!r} must be non-empty and contain no '/'")
        h, w = (int(v) for v in hw)
        features[f"observation.images.{cam}"] = {"dtype": "video", "shape": (h, w, 3),
                                                 "names": ["height", "width", "channels"]}
    return features


def camera_version_of(sidecar: dict, features: dict) -> int | None:
    """The :data:`CAMERA_VERSION` a dataset's images were recorded with (None: it has no cameras)."""
    if not any(k.startswith("observation.images.") for k in features):
        return None
    return int(sidecar.get("camera_version", 1))


def camera_renderer_of(sidecar: dict, features: dict) -> str | None:
    """The renderer that drew a dataset's images (:data:`DEFAULT_CAMERA_RENDERER` if it records none; None: it has
    no cameras)."""
    if not any(k.startswith("observation.images.") for k in features):
        return None
    return str(sidecar.get("camera_renderer", DEFAULT_CAMERA_RENDERER))


def is_schema1(features: dict) -> bool:
    """Features written by the schema-1 recorder (goals under ``observation.*_goal``)."""
    return ENV_STATE not in features and "observation.desired_goal" in features


def event_features(n_arms: int) -> dict[str, dict]:
    """The per-frame env events (:data:`~surrol_data.datasets.trajectory.EVENT_FLAGS`) of tasks that grasp: added to
    :func:`frame_features` by collectors whose env reports grasps. Optional: a dataset without them reads as
    before, with failed grasps and drops unknown."""
    arms = _arm_prefixes(n_arms)
    return {"complementary_info.grasped": {"dtype": "bool", "shape": (n_arms,), "names": [p + "grasped" for p in arms]},
            "complementary_info.drop": {"dtype": "bool", "shape": (1,), "names": ["drop"]}}


IS_INTERVENTION = "complementary_info.is_intervention"
INTERVENTION_ARMS = "complementary_info.intervention_arms"
POLICY_ACTION = "complementary_info.policy_action"
INTERVENTION_FEATURES = (IS_INTERVENTION, INTERVENTION_ARMS, POLICY_ACTION)


def intervention_features(n_arms: int, action_names) -> dict[str, dict]:
    """Who acted at each frame of an intervention session, added to :func:`frame_features` by its collector.

    ``is_intervention`` follows LeRobot's HIL-SERL convention (``lerobot.rl``: the actor's
    ``complementary_info["is_intervention"]``, stored by its replay buffer as a float32 of shape (1,), which its
    learner reads to send the operator's transitions to the offline buffer): 1.0 where the operator drove any arm.
    ``intervention_arms`` says which arm; ``policy_action`` is the policy's proposal beside the executed action."""
    arms = _arm_prefixes(n_arms)
    return {IS_INTERVENTION: _vector("float32", ["is_intervention"]),
            INTERVENTION_ARMS: _vector("bool", [p + "operator" for p in arms]),
            POLICY_ACTION: _vector("float32", [f"policy_{n}" for n in action_names])}


def dims_from_features(features: dict) -> dict:
    """Inverse of :func:`frame_features` for the dimensions: obs_dim, goal_dim, act_dim, n_arms, cameras."""
    if is_schema1(features):
        raise OutdatedSchemaError("written with surrol_data schema 1 (goals in observation.achieved_goal / "
                                  "desired_goal, no observation.environment_state): run `surrol-data upgrade "
                                  "DIR` to rewrite it in the current schema")
    try:
        env_dim = int(features[ENV_STATE]["shape"][0])
        return {
            "obs_dim": int(features["observation.state"]["shape"][0]),
            "goal_dim": env_dim // 2,
            "act_dim": int(features["action"]["shape"][0]),
            "n_arms": int(features["complementary_info.jaw_angle"]["shape"][0]),
            "cameras": {k.removeprefix("observation.images."): tuple(int(v) for v in ft["shape"][:2])
                        for k, ft in features.items() if k.startswith("observation.images.")},
        }
    except KeyError as e:
        raise ValueError(f"features lack {e.args[0]!r}: not a surrol_data frame schema (see frame_features)") from None


def names_from_features(features: dict) -> dict:
    """The ``*_names`` arguments of :func:`frame_features` that rebuild ``features`` (schema 2)."""
    goal_dim = dims_from_features(features)["goal_dim"]
    environment = list(features[ENV_STATE]["names"])
    return {"state_names": list(features["observation.state"]["names"]),
            "achieved_goal_names": environment[:goal_dim], "desired_goal_names": environment[goal_dim:],
            "action_names": list(features["action"]["names"])}


def split_environment_state(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(achieved goal, desired goal) of ``observation.environment_state`` rows (..., 2 * goal_dim)."""
    values = np.asarray(values)
    half = values.shape[-1] // 2
    return values[..., :half], values[..., half:]


def content_hash(frames: dict[str, np.ndarray], features: dict) -> str:
    """SHA-256 (hex, 32 chars) of an episode's stored frame columns: every non-video feature of ``features``,
    by name, as the (T, dim) array of its declared dtype. Equal for the same episode copied by merge/filter/
    split (values round-trip exactly), different after any change of a stored value."""
    import hashlib

    digest = hashlib.sha256()
    for name in sorted(features):
        ft = features[name]
        if ft["dtype"] in ("video", "image", "string") or name not in frames:
            continue
        arr = np.asarray(frames[name])
        arr = np.ascontiguousarray(arr.reshape(len(arr), -1), dtype=np.dtype(ft["dtype"]))
        digest.update(name.encode())
        digest.update(str(arr.shape).encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()[:32]


# Seals: per-episode columns of meta/episodes that make an edit after recording detectable. ``content_hash`` covers
# the frames (and finds duplicates); ``seal/provenance`` covers every provenance value, content_hash included, so
# it chains to the frames; ``seal/<video key>`` covers the compressed packets of the episode's video segment.
# Datasets recorded before seals existed have none (``validate`` checks whatever seals a dataset holds; one
# whose sidecar says ``"seals": 1`` must hold them all).
SEAL_PREFIX = "seal/"
PROVENANCE_SEAL = SEAL_PREFIX + "provenance"


def video_seal_column(video_key: str) -> str:
    return SEAL_PREFIX + video_key


def provenance_seal(provenance: dict) -> str:
    """SHA-256 (hex, 32 chars) of an episode's :data:`PROVENANCE_COLUMNS` values (canonical JSON). Equal for the
    row as recorded and as read back (parquet keeps each python type exactly); any edited value changes it."""
    import hashlib

    values = {}
    for key, typ in PROVENANCE_COLUMNS.items():
        value = provenance[key]
        values[key] = value.item() if isinstance(value, np.generic) else value
    text = json.dumps(values, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def utc_now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def _coerce(key: str, value, expected: type):
    """Value as exactly ``expected`` or ProvenanceError. Numpy scalars are accepted; lossy casts are not."""
    bad = ProvenanceError(f"provenance[{key!r}] = {value!r} ({type(value).__name__}): expected {expected.__name__}"
                          + (" (use -1 / nan / '' for 'unknown', never None)" if value is None else ""))
    if expected is bool:
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise bad
    if expected is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise bad
        return int(value)
    if expected is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise bad
        return float(value)
    if expected is str:
        if key in ("operator_params", "device_settings") and isinstance(value, (dict, list)):
            # JSON text keeps the column a plain string whatever the device/operator puts in it.
            return json.dumps(value, sort_keys=True, default=_json_default)
        if isinstance(value, str):
            return value
        raise bad
    raise TypeError(f"unsupported provenance type {expected}")  # pragma: no cover - schema bug


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def normalize_provenance(provenance: dict, trajectory=None, defaults: dict | None = None) -> dict:
    """Checked, complete provenance: every :data:`PROVENANCE_COLUMNS` key, in order, with its exact type.

    ``defaults`` (e.g. the recorder's task, env id, command, git commit) fill keys the caller left out;
    metric columns left out are computed from ``trajectory`` with
    :func:`surrol_data.datasets.metrics.trajectory_proficiency`; ``recorded_at`` defaults to now and
    ``package_version`` to the installed surrol_data. Raises :class:`ProvenanceError` naming the bad key.
    """
    if not isinstance(provenance, dict):
        raise ProvenanceError(f"provenance must be a dict, got {type(provenance).__name__}")
    unknown = sorted(set(provenance) - set(PROVENANCE_COLUMNS))
    if unknown:
        raise ProvenanceError(f"unknown provenance key(s) {unknown}; allowed: {list(PROVENANCE_COLUMNS)}")
    merged = {**_DEFAULTS, **(defaults or {}), **provenance}
    missing_metrics = [k for k in METRIC_COLUMNS if k not in merged]
    if missing_metrics:
        if trajectory is None:
            raise ProvenanceError(f"provenance lacks {missing_metrics} and no trajectory was given to compute them")
        from surrol_data.datasets.metrics import trajectory_proficiency

        prof = trajectory_proficiency(trajectory)
        computed = {"success": prof.success, "steps_to_success": prof.steps_to_success,
                    "path_length_cm": prof.path_length_cm, "jaw_closures": prof.jaw_closures,
                    "clutch_uses": prof.clutch_uses, "episode_steps": prof.steps}
        merged.update({k: computed[k] for k in missing_metrics})
    merged.setdefault("recorded_at", utc_now_iso())
    merged.setdefault("package_version", package_version())
    missing = [k for k in PROVENANCE_COLUMNS if k not in merged]
    if missing:
        raise ProvenanceError(f"provenance lacks required key(s) {missing}; required: {list(REQUIRED_PROVENANCE)}")
    out = {key: _coerce(key, merged[key], typ) for key, typ in PROVENANCE_COLUMNS.items()}
    for key, choices in PROVENANCE_CHOICES.items():
        if out[key] not in choices:
            raise ProvenanceError(f"provenance[{key!r}] = {out[key]!r}: expected one of {list(choices)}")
    for key in ("operator_params", "device_settings"):
        try:
            json.loads(out[key])
        except json.JSONDecodeError:
            raise ProvenanceError(f"provenance[{key!r}] must be JSON text or a dict, got {out[key]!r}") from None
    if out["steps_to_success"] < -1 or out["episode_steps"] < 0:
        raise ProvenanceError(f"provenance steps_to_success={out['steps_to_success']} / episode_steps="
                              f"{out['episode_steps']}: expected -1 or a step count, and a non-negative length")
    if trajectory is not None and out["episode_steps"] != len(trajectory):
        raise ProvenanceError(f"provenance['episode_steps'] = {out['episode_steps']} but the trajectory has "
                              f"{len(trajectory)} steps")
    return out


@functools.cache   # the installed version does not change while a process runs; the metadata scan costs ~2 ms
def package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("surrol-data")
    except PackageNotFoundError:
        return "0+unknown"

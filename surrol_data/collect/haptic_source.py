"""Haptic collection sessions: a person (or a simulated operator) drives the robot through a device.

One session = one env, one or two devices (one per PSM arm), one dataset. Per attempt:

1. ``env.reset(seed=...)`` (attempt ``i`` of a live session uses ``seed + i``; a replay uses each trace's seed),
   reset each device's :class:`~surrol_data.collect.mapping.ActionMapper`;
2. per env step: ``device.observe(obs, info)``, ``frame = device.read()``, ``step = mapper(frame)``,
   ``env.step(action)`` — paced to the control period for human devices, as fast as possible for the
   simulated operator and replays. The first frame of an attempt is the reference (zero motion);
3. the attempt ends ``STEPS_AFTER_SUCCESS`` steps after the first success (so the demo shows the goal held),
   at the horizon, when a replay's trace ends, when the operator redoes / discards it (keys ``r`` / ``f``
   in the terminal or the GUI window; ``Esc`` ends the session), or saves it as it stands (``Enter``);
4. a success (or any attempt with ``keep_failures``) is recorded with provenance and its device trace
   (:mod:`surrol_data.collect.devices.trace`).

An intervention session (``policy`` given; ``collect --source intervene``) runs the same loop with a policy acting:
at every step the policy proposes an action, and each arm executes it unless its operator holds the takeover control
(:data:`~surrol_data.collect.devices.base.BUTTON_TAKEOVER`: a key, the gamepad's right trigger, a Touch's third
button; ``space`` held takes every arm); then the arm executes the operator's. The device is read at every step, so
the hand's motion while the policy drives moves nothing (as under the clutch) and a takeover starts where the hand
is; the jaw command continues from the executed one. Every frame records who acted and the policy's proposal
(:func:`surrol_data.datasets.schema.intervention_features`); the episode's provenance names the policy and counts
the takeovers. ``--device operator`` makes the simulated operator a supervisor
(:class:`surrol_data.collect.operator.supervisor.Supervisor`; on a two-arm task one per arm,
:class:`surrol_data.collect.operator.arm_supervisor.ArmSupervisor`).

Durability: the recorder checkpoints after every episode (human episodes are precious and slow), so a
SIGKILL loses at most the episode in progress; Ctrl-C, SIGTERM, an unplugged device or any exception
finalize the dataset with every finished episode.
"""

from __future__ import annotations

import contextlib
import functools
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from surrol_data.collect.devices import (BUTTON_TAKEOVER, HUMAN_DEVICES, Device, DeviceError, check_devices,
                                         default_sides, open_device)
from surrol_data.collect.devices.trace import mapping_from_dict, trace_path, write_trace
from surrol_data.collect.mapping import ActionMapper, MappedStep, MappingSettings, frame_defaults, view_to_action
from surrol_data.collect.operator import SimulatedOperator
from surrol_data.collect.operator.arm_supervisor import arm_supervisors
from surrol_data.collect.operator.supervisor import Supervisor
from surrol_data.collect.rollout import Policy, bind_policy, policy_action, start_episode
from surrol_data.collect.script_source import features_for, first_seed, make_env, renderer_of
from surrol_data.datasets.interventions import trajectory_interventions
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.schema import CAMERA_VERSION, DEFAULT_CAMERA_RENDERER, intervention_features
from surrol_data.datasets.trajectory import TrajectoryBuilder
from surrol_data.envs import env_id as make_env_id
from surrol_data.envs.names import dimension_names, is_ecm_action
from surrol_data.envs.units import ACTION_POSITION_M, ACTION_YAW_RAD, CONTROL_PERIOD_S
from surrol_data.render.display import has_display

# SurRoL-v2 recorded human NeedlePick demos with a 150-step horizon, 3× the scripted 50: people need the margin.
HUMAN_HORIZON_FACTOR = 3
# Tasks whose registered horizon is a script's, too short for a person even at that factor: the steps a person's
# horizon is computed from instead. PegTransfer moves one block onto one peg, the work of MatchBoard's one block
# into a groove (registered at 100 steps); the reference's 50 was set for its script.
HUMAN_PACE_STEPS = {"PegTransfer": 100}
STEPS_AFTER_SUCCESS = 2
SKILLS = ("expert", "novice", "unknown")


@dataclass
class HapticResult:
    root: Path
    kept: int = 0
    attempts: int = 0            # finished attempts (success or failure); redone / discarded ones not counted
    failures: int = 0
    discarded: int = 0
    redone: int = 0
    seeds: list[int] = field(default_factory=list)
    episode_indices: list[int] = field(default_factory=list)
    takeovers: int = 0           # an intervention session: takeovers over the kept episodes
    intervention_frames: int = 0
    frames: int = 0              # frames of the kept episodes
    ended_by: str = ""           # "done", "operator" (Esc), "attempts" (max attempts reached), "traces" (replay)

    @property
    def success_rate(self) -> float:
        return (self.attempts - self.failures) / self.attempts if self.attempts else float("nan")


def collect_haptic(task: str, episodes: int, out: str | Path, *, device: str | Sequence[Device] = "touch",
                   operator_id: str = "", skill: str = "unknown", sides: Sequence[str | None] | None = None,
                   mapping: MappingSettings | Sequence[MappingSettings] | None = None,
                   trace: str | Path | None = None, seed: int | None = 0, max_steps: int | None = None,
                   keep_failures: bool = False, append: bool = False, gui: bool | None = None,
                   rerun_live: str | None = None, max_attempts: int | None = None, progress: bool = True,
                   command: str | None = None, library: str | Path | None = None,
                   realtime: bool | None = None, key_tracker=None, on_step=None,
                   env_kwargs: dict | None = None, profile: str | None = None,
                   policy: Policy | str | None = None, policy_info: dict | None = None,
                   timeout_needs_save: bool = False, episode_sink=None, on_reset=None) -> HapticResult:
    """Record ``episodes`` kept teleoperated episodes of ``task`` into the dataset at ``out``.

    ``device``: a name of :data:`surrol_data.collect.devices.DEVICE_NAMES` (one device per arm is built with
    :func:`open_device`), or ready-made :class:`Device` objects (one per arm). ``sides``: per-arm device side
    (Touch: left/right; default right→PSM1, left→PSM2 for two arms). ``mapping``: one setting for all
    devices or one per device. ``trace``: what ``replay`` plays. ``gui``: PyBullet window (default: when a
    display exists and the device is a human one). ``rerun_live``: ``"spawn"`` (start a viewer), a
    ``rerun+http://`` URL, or an ``.rrd`` path to stream the session to. ``max_attempts``: stop after that
    many finished attempts (default 3 × episodes). ``realtime``: pace steps to the task's control period
    (:func:`control_period_s`; default: for human devices only). ``key_tracker``: the key source of a host window
    (the training GUI) for keyboard devices and the session keys; the window shows the keys, so the session does
    not print them. ``on_step(env, step, obs, info, flags)``: called after every env step
    (``step`` counts from 1 in each attempt), e.g. to draw a frame; ``on_reset(env, obs, info)``: after each attempt's
    reset, before its first step. ``env_kwargs``: extra ``gym.make`` arguments.
    ``profile``: the simulated operator's profile when not the skill's natural one, e.g. ``expert_matched`` (see
    :data:`surrol_data.collect.operator.profiles.MATCHED_PROFILES`); its skill must be ``skill``.
    ``policy``: an intervention session (see the module docstring): the policy acts and the operator takes over;
    ``policy_info`` is what the provenance records of it (spec, content hash, algorithm, training data).
    ``timeout_needs_save``: an attempt that runs out of time without success waits for a session key: the save key
    keeps it, redo / discard / end drop it (the training GUI; without a key source it changes nothing).
    ``episode_sink(traj, provenance, frames, meta) -> index``: records each kept episode instead of a recorder the
    session opens on ``out`` (the web console's sessions hand their episodes to its one writer; the default is
    :func:`record_episode`).
    """
    if episodes <= 0:
        raise ValueError(f"the number of episodes must be positive, got {episodes}")
    if skill not in SKILLS:
        raise ValueError(f"--skill must be one of {', '.join(SKILLS)}, got {skill!r}")
    names = [device] if isinstance(device, str) else [d.name for d in device]
    if profile is not None:
        from surrol_data.collect.operator.profiles import ALL_PROFILES

        if names != ["operator"]:
            raise ValueError(f"--profile chooses a simulated operator's profile; it needs --device operator, not {names}")
        if profile not in ALL_PROFILES:
            raise ValueError(f"unknown operator profile {profile!r}; choose one of {sorted(ALL_PROFILES)}")
        if skill == "unknown":
            skill = ALL_PROFILES[profile].skill
        if ALL_PROFILES[profile].skill != skill:
            raise ValueError(f"profile {profile!r} is a {ALL_PROFILES[profile].skill} profile, but --skill is {skill!r}")
    if isinstance(device, str) and device == "operator" and skill == "unknown":
        raise ValueError("the simulated operator needs --skill expert or --skill novice")
    human = any(n in HUMAN_DEVICES for n in names)
    if gui is None:
        gui = human and has_display()
    if gui and not has_display():
        raise ValueError("--gui needs a display (DISPLAY / WAYLAND_DISPLAY is unset); run without --gui, "
                         "optionally with --rerun-live")
    import surrol_data.envs  # noqa: F401  (registers the ids)

    eid = make_env_id(task)
    if isinstance(device, str):   # a device to plug in is found (or said missing) before the env and dataset start
        check_devices(device, sides or default_sides(device, _device_count(eid)), library)
    seed = first_seed(out, append, seed, "haptic" if policy is None else "intervention")
    registered = gym.spec(eid).max_episode_steps
    replay_horizon = _replay_horizon(trace) if names == ["replay"] else None
    horizon = max_steps or replay_horizon or _human_horizon(eid, registered)
    env = make_env(eid, env_kwargs or {}, max_episode_steps=horizon, **({"render_mode": "human"} if gui else {}))
    try:
        return _Session(env, eid, episodes, out, device, names, operator_id, skill, sides, mapping, trace, seed,
                        horizon, keep_failures, append, gui, rerun_live, max_attempts or 3 * episodes, progress,
                        command, library, realtime, key_tracker, on_step, profile, policy, policy_info,
                        timeout_needs_save, renderer_of(env_kwargs), episode_sink, on_reset).run()
    finally:
        env.close()


def parse_mapping(overrides: Sequence[str], base: MappingSettings | None = None) -> MappingSettings:
    """``["motion_scale=0.4", "axis_sign=1,-1,1"]`` → MappingSettings (the CLI's ``--mapping`` options)."""
    values = (base or MappingSettings()).as_dict()
    for item in overrides:   # a frame given first brings its natural axis map; later items may override it
        key, _, text = item.partition("=")
        if key.strip() == "frame":
            try:
                values.update(frame_defaults(text.strip()))
            except ValueError as e:
                raise ValueError(f"--mapping {item!r}: {e}") from None
    for item in overrides:
        if item.partition("=")[0].strip() == "frame":
            continue
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or key not in values:
            raise ValueError(f"--mapping {item!r}: expected NAME=VALUE with NAME one of {', '.join(values)}")
        try:
            parts = [float(v) for v in text.split(",")]
        except ValueError:
            raise ValueError(f"--mapping {item!r}: {text!r} is not a number or a comma-separated list") from None
        old = values[key]
        if isinstance(old, tuple):
            if len(parts) != len(old):
                raise ValueError(f"--mapping {key} needs {len(old)} comma-separated values, got {text!r}")
            values[key] = tuple(int(v) if isinstance(o, int) else v for v, o in zip(parts, old, strict=True))
        elif len(parts) != 1:
            raise ValueError(f"--mapping {key} takes one value, got {text!r}")
        else:
            values[key] = int(parts[0]) if isinstance(old, int) else parts[0]
    if sorted(values["axis_permutation"]) != [0, 1, 2] or not 0 <= values["rotation_axis"] <= 2:
        raise ValueError(f"--mapping: axis_permutation {values['axis_permutation']} must be a permutation of 0,1,2 "
                         f"and rotation_axis ({values['rotation_axis']}) one of 0, 1, 2")
    return mapping_from_dict(values)


def human_horizon(task: str) -> int:
    """The horizon of a person's (or a supervised policy's) episode of ``task``, as a session without
    ``max_steps`` uses."""
    import surrol_data.envs  # noqa: F401  (registers the ids)

    eid = make_env_id(task)
    return _human_horizon(eid, gym.spec(eid).max_episode_steps)


def control_period_s(env) -> float:
    """Simulated seconds per step of ``env``: an ECM task (one camera, a 1-, 3- or 4-D action) steps every 0.1 s,
    the arms every 0.2 s. A session paced for a person waits this long between steps."""
    from surrol_data.envs.physics import ECM_CONTROL_PERIOD_S

    return ECM_CONTROL_PERIOD_S if is_ecm_action(env.action_space.shape[0]) else CONTROL_PERIOD_S


def _human_horizon(eid: str, registered: int) -> int:
    """A person's horizon: HUMAN_HORIZON_FACTOR × the registered one (or the task's HUMAN_PACE_STEPS) in time, not
    steps (an ECM task's 0.1 s steps get twice as many), and twice that where two hands take turns (one waits while
    the other works)."""
    from surrol_data.envs.physics import ECM_CONTROL_PERIOD_S

    registered = HUMAN_PACE_STEPS.get(eid.split("/")[-1].rsplit("-v", 1)[0], registered)
    action_dim = _action_dim(eid)
    if is_ecm_action(action_dim):      # one camera, 0.1 s steps
        return round(HUMAN_HORIZON_FACTOR * registered * CONTROL_PERIOD_S / ECM_CONTROL_PERIOD_S)
    return HUMAN_HORIZON_FACTOR * registered * (action_dim // 5)


def _action_dim(eid: str) -> int:
    """The action size of ``eid``, from its env class alone (no env is made)."""
    from importlib import import_module

    module, name = gym.spec(eid).entry_point.split(":")
    return getattr(import_module(module), name).ACTION_DIM


def _device_count(eid: str) -> int:
    """Devices a session of ``eid`` needs: one per PSM (a 5-D half of the action), one for an ECM task's camera."""
    action_dim = _action_dim(eid)
    return 1 if is_ecm_action(action_dim) else action_dim // 5


def _replay_horizon(trace) -> int | None:
    from surrol_data.collect.devices.trace import read_trace, trace_files

    if trace is None:
        return None
    return max(int(read_trace(f).meta.get("horizon", 0)) for f in trace_files(trace)) or None


class _Session:
    """The attempt loop of :func:`collect_haptic` (state that lives for one session)."""

    def __init__(self, env, eid, episodes, out, device, names, operator_id, skill, sides, mapping, trace, seed,
                 horizon, keep_failures, append, gui, rerun_live, max_attempts, progress, command, library,
                 realtime, key_tracker=None, on_step=None, profile=None, policy=None, policy_info=None,
                 timeout_needs_save=False, camera_renderer=DEFAULT_CAMERA_RENDERER, episode_sink=None, on_reset=None):
        self.timeout_needs_save = timeout_needs_save
        self.env, self.eid, self.episodes, self.out = env, eid, episodes, Path(out)
        self.task = eid.split("/")[1].rsplit("-v", 1)[0]
        self.operator_id, self.skill, self.seed, self.horizon = operator_id, skill, seed, horizon
        self.keep_failures, self.max_attempts, self.progress = keep_failures, max_attempts, progress
        self.gui, self.command, self.on_step, self.on_reset = gui, command, on_step, on_reset
        act_dim = env.action_space.shape[0]
        self.ecm_only = is_ecm_action(act_dim)   # one camera, one device
        self.control_period_s = control_period_s(env)
        n_devices = 1 if self.ecm_only else act_dim // 5

        sides = list(sides) if sides is not None else default_sides(names[0], n_devices)
        if len(sides) != n_devices:
            raise ValueError(f"{self.task} needs {n_devices} device(s), {len(sides)} side(s) given ({sides})")
        if mapping is None or isinstance(mapping, MappingSettings):
            self.mappings = [mapping or MappingSettings()] * n_devices
        else:
            self.mappings = list(mapping)
        if len(self.mappings) != n_devices:
            raise ValueError(f"{self.task} needs {n_devices} mapping setting(s), {len(self.mappings)} given")
        self.sides = sides

        # Ready-made keyboard devices bring their key source; the session keys are read from the same one.
        given = [] if isinstance(device, str) else list(device)
        # A host window that brings its key source shows the keys itself (the training GUI's HUD): the list of
        # session keys is printed only for the key sources the session opens (terminal, PyBullet window).
        self.keys_on_screen = key_tracker is not None
        self.key_tracker = key_tracker or next((d.tracker for d in given if getattr(d, "tracker", None) is not None),
                                               None) or self._key_tracker(names)
        if isinstance(device, str):
            self.devices = [open_device(device, arm=i, side=sides[i], env=env.unwrapped, mapping=self.mappings[i],
                                        skill=profile or skill, operator_id=operator_id, seed=seed, trace=trace,
                                        key_tracker=self.key_tracker, library=library)
                            for i in range(n_devices)]
        else:
            self.devices = list(device)
            if len(self.devices) != n_devices:
                raise ValueError(f"{self.task} needs {n_devices} device(s), {len(self.devices)} given")
        operators = [d for d in self.devices if isinstance(d, SimulatedOperator)]
        self.policy = None if policy is None else bind_policy(env, policy)
        self.policy_info = dict(policy_info or {})
        if self.policy is not None and operators:
            if len(operators) > 1:   # a two-arm task: one watch per hand, each takes its own arm over
                supervisors = iter(arm_supervisors(operators))
            else:
                supervisors = iter([Supervisor(operators[0])])
            self.devices = [next(supervisors) if isinstance(d, SimulatedOperator) else d for d in self.devices]
        elif len(operators) > 1:   # two simulated hands on a bimanual task: one person
            SimulatedOperator.work_together(operators)
        # ECM tasks: the camera moves by camera_motion_scale × the hand motion and rolls by rotation_scale × the
        # hand roll. The mapping's actions assume the PSM's units (1 = 1 cm, 30°); an ECM task may use others
        # (StaticTrack's 1 mm, MisOrient's 3°), declared as ACTION_TRANSLATION_M / ACTION_ROTATION_RAD.
        task_env = env.unwrapped
        self.camera_rescale = np.array([*[ACTION_POSITION_M / getattr(task_env, "ACTION_TRANSLATION_M",
                                                                      ACTION_POSITION_M)] * 3,
                                        ACTION_YAW_RAD / getattr(task_env, "ACTION_ROTATION_RAD", ACTION_YAW_RAD)])
        self.replay = all(d.name == "replay" for d in self.devices)
        self.realtime = any(getattr(d, "realtime", False) for d in self.devices) if realtime is None else realtime
        self.live = _LiveStream(rerun_live, self.task) if rerun_live else None
        features = features_for(env)
        if self.policy is not None:
            names = dimension_names(env)
            features.update(intervention_features(names.n_arms, names.action))
        if episode_sink is not None:   # another process writes the dataset (the web console's one writer)
            self.recorder, self.episode_sink = contextlib.nullcontext(), episode_sink
        else:
            self.recorder = DatasetRecorder(self.out, task=self.task, env_id=eid,
                                            task_description=env.unwrapped.TASK, features=features, append=append,
                                            command=command, checkpoint_every=1,
                                            robot_type=dimension_names(env).robot_type,
                                            camera_renderer=camera_renderer,
                                            lazy=False)   # lerobot's import before the operator starts, not after
            self.episode_sink = functools.partial(record_episode, self.recorder, self.out)
        self.result = HapticResult(root=self.out)

    def _key_tracker(self, names):
        """One key source for keyboard devices and the session keys (only for people at a terminal or window)."""
        if not any(n in HUMAN_DEVICES for n in names):
            return None
        from surrol_data.collect.devices.keyboard import KeyTracker, PyBulletKeys, TerminalKeys

        if self.gui:
            return KeyTracker(PyBulletKeys(self.env.unwrapped.client))
        if sys.stdin.isatty():
            return KeyTracker(TerminalKeys())
        return None

    # ------------------------------------------------------------------ the loop

    def run(self) -> HapticResult:
        res = self.result
        n_traces = self.devices[0].episodes if self.replay else None
        target = min(self.episodes, n_traces) if n_traces is not None else self.episodes
        bar = tqdm(total=target, desc=f"collect {self.task} (haptic, {self.devices[0].name})", unit="ep",
                   disable=not self.progress)
        connected: list[Device] = []
        seed_offset = 0
        try:
            with self.recorder:
                for dev in self.devices:
                    dev.connect()
                    connected.append(dev)
                if self.key_tracker is not None:
                    self.key_tracker.start()
                    if self.realtime and not self.keys_on_screen:
                        tqdm.write("keys: r = redo this attempt, f = discard it, Enter = save it as it stands, "
                                   "Esc = end the session (Ctrl-C in a terminal)")
                        if self.policy is not None:
                            tqdm.write("the policy acts: hold space (or the device's takeover control) to take over, "
                                       "release it to hand back")
                while res.kept < target and res.attempts < self.max_attempts:
                    replayed = None
                    if self.replay:   # trace i holds attempt i's seed, mapping and operator
                        replayed = [d.start_episode(seed_offset) for d in self.devices]
                        attempt_seed = replayed[0].seed
                    else:
                        attempt_seed = self.seed + seed_offset
                    outcome, traj, frames = self._attempt(attempt_seed, replayed)
                    if outcome == "quit":
                        res.ended_by = "operator"
                        break
                    if outcome == "redo":
                        res.redone += 1
                        continue
                    seed_offset += 1
                    if outcome == "discard":
                        res.discarded += 1
                        continue
                    res.attempts += 1
                    if not traj.is_success:
                        res.failures += 1
                        # a replay keeps what it replays: the traces are of episodes that were kept
                        if not (self.keep_failures or self.replay):
                            continue
                    self._record(traj, frames, attempt_seed, replayed)
                    res.seeds.append(attempt_seed)
                    bar.update(1)
                    bar.set_postfix(success=f"{res.success_rate:.2f}", refresh=False)
                else:
                    res.ended_by = "done" if res.kept >= target else "attempts"
        except DeviceError as e:
            raise DeviceError(f"{e} — {self._what_is_kept()}") from e
        finally:
            bar.close()
            for dev in reversed(connected):
                dev.disconnect()
            if self.key_tracker is not None:
                self.key_tracker.stop()
        if res.ended_by == "attempts":
            raise RuntimeError(f"only {res.kept} of {self.episodes} episodes of {self.task} succeeded in "
                               f"{res.attempts} attempts ({self._what_is_kept()}); use "
                               "--keep-failures to record failures too")
        return res

    def _what_is_kept(self) -> str:
        """Where this session's finished episodes are, as the disk has it once the recorder has closed: a dataset
        that no episode reached is not made, and is not named as if it were."""
        if not (self.out / "meta" / "info.json").is_file():
            return f"nothing was recorded (there is no dataset at {self.out})"
        return (f"the {self.result.kept} finished episode(s) of this session are saved in {self.out} (continue with "
                "--append)")

    def _attempt(self, attempt_seed: int, replayed):
        env = self.env
        settings = [t.mapping(i) for i, t in enumerate(replayed)] if replayed else self.mappings
        mappers = [ActionMapper(m) for m in settings]
        obs, info = env.reset(seed=attempt_seed)
        if self.on_reset is not None:
            self.on_reset(env, obs, info)
        held = np.asarray(info.get("grasped", False)).reshape(-1)
        for mapper, holds in zip(mappers, held):
            if holds:    # the task starts with the object in this hand: the jaw command starts closed
                mapper.jaw = -1.0
        if self.policy is not None:
            start_episode(self.policy)
        builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
        frames: list[list] = [[] for _ in self.devices]
        last_jaw = np.array([m.jaw for m in mappers], np.float32)
        driving = [self.policy is None] * len(self.devices)    # who drives each arm: the operator, or the policy
        after_success = None
        saved = False
        start = time.monotonic()
        if self.live:
            self.live.begin(attempt_seed)
        for k in range(self.horizon):
            if self.realtime:   # one step per control period, as the arm would move under a human hand
                delay = start + k * self.control_period_s - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            command = self._session_command()
            if command == "save":
                if k > 0:   # end the attempt here and record it as it stands
                    saved = True
                    break
            elif command is not None:
                return command, None, None
            if self.replay and any(d.exhausted for d in self.devices):
                break
            proposed = None if self.policy is None else policy_action(self.policy, obs, env.action_space)
            everything = self._takeover_key_held()
            steps: list[MappedStep] = []
            for arm, (dev, mapper, log) in enumerate(zip(self.devices, mappers, frames, strict=True)):
                dev.observe(obs, info)
                frame = dev.read()
                log.append(frame)
                if proposed is not None:
                    takes = everything or bool(frame.buttons & BUTTON_TAKEOVER)
                    if takes and not driving[arm] and not self.ecm_only:
                        mapper.jaw = float(last_jaw[arm])   # the jaw goes on from where the policy left it
                    driving[arm] = takes
                view = view_to_action(env, arm) if mapper.settings.frame == "camera" else None
                steps.append(mapper(frame, view))
            action = self._action(steps, mappers)
            if proposed is not None:
                action = self._merge(proposed, action, driving)
            obs, reward, terminated, truncated, info = env.step(action)
            last_jaw = action[4::5] if not self.ecm_only else last_jaw
            # Device flags of the arms the operator drove (buttons pressed while the policy drives act on nothing).
            acting = [s for s, d in zip(steps, driving, strict=True) if d]
            flags = {"clutch": any(s.clutch for s in acting), "jaw_button": any(s.jaw_button for s in acting)}
            builder.add(action, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                        flags=flags, info=info, intervention=None if proposed is None else list(driving),
                        policy_action=proposed)
            if proposed is not None:
                flags = {**flags, "operator": any(driving)}   # for the live view and on_step: who acted
            if self.live:
                self.live.step(k, obs, action, info, flags)
            if self.on_step is not None:   # and each arm's buttons (a HUD shows both arms')
                self.on_step(env, k + 1, obs, info,
                             {**flags, "clutches": [s.clutch and d for s, d in zip(steps, driving, strict=True)],
                              "jaw_buttons": [s.jaw_button and d for s, d in zip(steps, driving, strict=True)]})
            if info["is_success"] and after_success is None:
                after_success = STEPS_AFTER_SUCCESS
            elif after_success is not None:
                after_success -= 1
            if terminated or truncated or after_success == 0:
                break
        self._duration = time.monotonic() - start
        if self.timeout_needs_save and not saved and after_success is None and self.key_tracker is not None:
            command = self._await_decision()   # out of time: kept only if the operator saves it
            if command != "save":
                return command, None, None
        return "done", builder.build(), frames

    def _await_decision(self) -> str:
        """The session key pressed after an attempt ran out of time (the window keeps drawing meanwhile)."""
        while True:
            command = self._session_command()
            if command is not None:
                return command
            time.sleep(0.02)

    def _action(self, steps: list[MappedStep], mappers: list[ActionMapper]) -> np.ndarray:
        space = self.env.action_space
        if self.ecm_only:
            s, settings = steps[0], mappers[0].settings
            # ECM tasks are driven by the device without holding both buttons: its motion at the camera scale.
            camera = s.camera if s.camera_mode else np.concatenate(
                [s.arm[:3] * settings.camera_motion_scale / settings.motion_scale, s.arm[3:4]])
            camera = camera * self.camera_rescale
            dim = space.shape[0]
            action = camera[3:4] if dim == 1 else camera[:dim]
        else:
            action = np.concatenate([s.arm for s in steps])
        # Record exactly what the env executes (it clips too).
        return np.clip(np.asarray(action, np.float32), space.low, space.high)

    def _merge(self, proposed: np.ndarray, operator: np.ndarray, driving: list[bool]) -> np.ndarray:
        """The executed action: per arm the operator's where they hold the takeover control, else the policy's."""
        if self.ecm_only:
            return operator if driving[0] else proposed
        action = proposed.copy()
        for arm, drives in enumerate(driving):
            if drives:
                action[5 * arm:5 * arm + 5] = operator[5 * arm:5 * arm + 5]
        return action

    def _takeover_key_held(self) -> bool:
        """The session's takeover key (``space``) held: the operator takes every arm (devices without a control)."""
        if self.policy is None or self.key_tracker is None:
            return False
        from surrol_data.collect.devices.keyboard import TAKEOVER_KEY

        return TAKEOVER_KEY in self.key_tracker.held()

    def _session_command(self) -> str | None:
        if self.key_tracker is None:
            return None
        from surrol_data.collect.devices.keyboard import DISCARD_KEY, QUIT_KEY, REDO_KEY, SAVE_KEY

        self.key_tracker.update()
        pressed = self.key_tracker.pop_pressed()
        for key, command in ((QUIT_KEY, "quit"), (REDO_KEY, "redo"), (DISCARD_KEY, "discard"), (SAVE_KEY, "save")):
            if key in pressed:
                return command
        return None

    def _record(self, traj, frames, attempt_seed: int, replayed) -> None:
        simulated = any(d.name == "simulated-operator" for d in self.devices)
        mappings = [t.mapping(i) for i, t in enumerate(replayed)] if replayed else self.mappings
        device_settings = {
            "devices": [{"name": d.name, "side": side or "", "mapping": m.as_dict(), "settings": d.settings()}
                        for d, side, m in zip(self.devices, self.sides, mappings, strict=True)],
            # The hand's frame per device (camera: the endoscope image of this camera version; robot: the
            # action's axes); recorded actions are in the robot's frame either way.
            "mapping_frames": [m.frame for m in mappings], "camera_version": CAMERA_VERSION,
            "horizon": self.horizon, "control_period_s": self.control_period_s, "realtime": self.realtime,
            "steps_after_success": STEPS_AFTER_SUCCESS,
        }
        if replayed:
            meta = replayed[0].meta
            device_settings["replay_of"] = {"devices": meta.get("devices", []), "episode_index": meta.get("episode_index", -1),
                                            "dataset": meta.get("dataset", "")}
            operator = {k: meta[k] for k in ("operator_id", "skill", "operator_simulated", "operator_params")}
        else:
            operator = {"operator_id": self.operator_id, "skill": self.skill, "operator_simulated": simulated,
                        "operator_params": json.dumps(self.devices[0].settings(), sort_keys=True, default=str)
                        if simulated else "{}"}
        if self.policy is not None:
            counts = trajectory_interventions(traj)
            device_settings["policy"] = self.policy_info
            device_settings["intervention"] = counts.as_dict()
            supervisors = [(arm, d) for arm, d in enumerate(self.devices) if isinstance(d, Supervisor)]
            if supervisors:   # [seconds, event], and on a two-arm task the arm: [seconds, event, arm], in time order
                device_settings["supervisor_events"] = sorted(
                    ([round(t, 3), e] + ([arm] if len(self.devices) > 1 else []) for arm, d in supervisors
                     for t, e in d.events), key=lambda row: (row[0], row[2:]))
        provenance = {"source": "haptic" if self.policy is None else "intervention", "device": self.devices[0].name,
                      **operator,
                      "device_settings": json.dumps(device_settings, sort_keys=True, default=str),
                      "seed": attempt_seed, "duration_s": self._duration}
        meta = {"task": self.task, "env_id": self.eid, "seed": attempt_seed, "horizon": self.horizon,
                "success": traj.is_success, "devices": [d.name for d in self.devices],
                "sides": [s or "" for s in self.sides], "mapping": [m.as_dict() for m in mappings], **operator}
        index = self.episode_sink(traj, provenance, frames, meta)
        self.result.kept += 1
        self.result.episode_indices.append(index)
        self.result.frames += len(traj)
        if self.policy is not None:
            self.result.takeovers += counts.takeovers
            self.result.intervention_frames += counts.intervention_frames


def record_episode(recorder: DatasetRecorder, out: str | Path, traj, provenance: dict, frames, meta: dict) -> int:
    """Record one haptic episode and its device trace into the dataset at ``out`` that ``recorder`` writes; the
    episode's index. ``meta`` (the trace's) gets the episode's index and the dataset's path.

    The trace goes to disk before the episode (a kill in between leaves a trace of no episode, which repair moves
    aside, never an episode without its trace); signals wait until both are written."""
    out = Path(out)
    with recorder.hold_signals():
        index = recorder.num_episodes
        meta = {**meta, "episode_index": index, "dataset": str(out.resolve())}
        path = write_trace(trace_path(out, index), frames, traj.action, meta)
        try:
            recorded = recorder.record(traj, provenance)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        assert recorded == index, (recorded, index)
    return index


class _LiveStream:
    """Streams each step to Rerun while the session runs: tool tip, goal, action channels, device flags."""

    def __init__(self, target: str, task: str):
        import rerun as rr

        from surrol_data.viz.rerun_log import APPLICATION_ID

        self.rr = rr
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=f"haptic-{task}-{time.time_ns()}")
        if target == "spawn":
            self.rec.spawn()
        elif target.endswith(".rrd"):
            self.rec.save(target)
        else:
            self.rec.connect_grpc(target)
        self.attempt = -1

    def begin(self, seed: int) -> None:
        self.attempt += 1
        self.prefix = f"live/attempt{self.attempt}_seed{seed}"

    def step(self, k: int, obs: dict, action: np.ndarray, info: dict, flags: dict) -> None:
        rr, rec = self.rr, self.rec
        rec.set_time("step", sequence=k + 1)
        rec.log(f"{self.prefix}/tip", rr.Points3D(np.asarray(info["tip_position"]).reshape(-1, 3), radii=0.001))
        rec.log(f"{self.prefix}/goal", rr.Points3D(np.asarray(obs["desired_goal"]).reshape(-1, 3), radii=0.002))
        for i, value in enumerate(np.asarray(action, np.float64)):
            rec.log(f"{self.prefix}/action/a{i}", rr.Scalars(value))
        for name, value in flags.items():
            rec.log(f"{self.prefix}/flags/{name}", rr.Scalars(float(value)))
        rec.log(f"{self.prefix}/success", rr.Scalars(float(info["is_success"])))

"""Scripted demonstrations: roll each task's linear-waypoint oracle and record the episodes with provenance."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from surrol_data.collect.rollout import ORACLE, rollout
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.schema import DEFAULT_CAMERA_RENDERER, event_features, frame_features
from surrol_data.datasets.trajectory import ENV_CAMERA
from surrol_data.envs import env_id as make_env_id
from surrol_data.envs.names import dimension_names, is_ecm_action


@dataclass
class CollectResult:
    root: Path
    kept: int = 0
    attempts: int = 0
    failures: int = 0
    seeds: list[int] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return (self.attempts - self.failures) / self.attempts if self.attempts else float("nan")


def features_for(env: gym.Env) -> dict:
    """The dataset features of ``env``'s episodes; an env made with ``camera=True`` adds the endoscope video."""
    spaces = env.observation_space
    names = dimension_names(env)   # one tool per PSM; an ECM task's one tool is the camera
    cameras = {ENV_CAMERA: tuple(spaces["image"].shape[:2])} if "image" in spaces.spaces else None
    features = frame_features(obs_dim=spaces["observation"].shape[0], goal_dim=spaces["desired_goal"].shape[0],
                              act_dim=env.action_space.shape[0], n_arms=names.n_arms, state_names=names.state,
                              achieved_goal_names=names.achieved_goal, desired_goal_names=names.desired_goal,
                              action_names=names.action, cameras=cameras)
    if hasattr(env.unwrapped, "grasp") or hasattr(env.unwrapped, "grasps"):   # the env reports grasps and drops
        features.update(event_features(names.n_arms))
    return features


def camera_kwargs(camera_size: tuple[int, int] | None, renderer: str = DEFAULT_CAMERA_RENDERER) -> dict:
    """``gym.make`` arguments that add the endoscope image (``camera_size`` = (width, height)) drawn by ``renderer``
    (``"tiny"`` or ``"panda3d"``, see :func:`surrol_data.envs.camera.make_camera`) to the observation."""
    if camera_size is None:
        return {}
    return {"camera": True, "camera_size": tuple(int(v) for v in camera_size), "camera_renderer": renderer}


def renderer_of(env_kwargs: dict | None) -> str:
    """The renderer that ``gym.make(..., **env_kwargs)`` draws the endoscope with (what the dataset records)."""
    return (env_kwargs or {}).get("camera_renderer", DEFAULT_CAMERA_RENDERER)


def make_env(eid: str, env_kwargs: dict, **kwargs) -> gym.Env:
    """``gym.make(eid, ...)``; a camera asked of a task that has none is a clear error, not a TypeError."""
    try:
        return gym.make(eid, **kwargs, **env_kwargs)
    except TypeError as e:
        if "camera" in env_kwargs and "camera" in str(e):
            raise ValueError(f"{eid} has no endoscope camera option (ECM tasks are the camera); record it without "
                             "--camera") from None
        raise


def first_seed(out: str | Path, append: bool, seed: int | None, source: str) -> int:
    """The seed of the first attempt: ``seed`` if given; with ``append`` to an existing dataset, one past the
    largest seed its ``source`` episodes recorded (so appending never re-records an episode); else 0."""
    if seed is not None:
        return int(seed)
    out = Path(out)
    if not append or not (out / "meta").is_dir():
        return 0
    from surrol_data.datasets.guard import ensure_finished
    from surrol_data.datasets.reader import DatasetReader

    ensure_finished(out)   # a recording killed before it created its dataset has no info.json until this repair
    if not (out / "meta" / "info.json").exists():
        return 0
    episodes = DatasetReader(out).episodes
    if "seed" not in episodes.columns or "source" not in episodes.columns:
        return 0
    seeds = episodes.loc[episodes["source"] == source, "seed"]
    return int(seeds.max()) + 1 if len(seeds) else 0


class PacedOracle:
    """The task's oracle at a fraction ``speed`` of its pace: its motion (position and rotation) scaled by
    ``speed``, its jaw command as is. The oracle is closed-loop, so it still reaches every waypoint, in about
    1/speed as many steps along about the same path. The paper matched its script demos to its human ones
    (109 steps); ``speed`` is that setting (:data:`SCRIPT_SPEED_MATCHED`)."""

    def __init__(self, env: gym.Env, speed: float):
        if not 0.0 < speed <= 1.0:
            raise ValueError(f"oracle speed must be in (0, 1], got {speed}")
        self.oracle = env.unwrapped.oracle_action
        self.speed = float(speed)

    def __call__(self, obs: dict):
        action = np.array(self.oracle(obs), np.float32)
        if is_ecm_action(action.size):       # every dimension is camera motion
            return action * self.speed
        arms = action.reshape(-1, 5)         # per PSM arm: dx, dy, dz, d_rot, jaw
        arms[:, :4] *= self.speed
        return arms.reshape(-1)


def _rollouts_here(env: gym.Env, policy, seeds):
    """(seed, trajectory, seconds) of each seed, rolled out in this process."""
    for s in seeds:
        t0 = time.perf_counter()
        traj = rollout(env, policy, s)
        yield s, traj, time.perf_counter() - t0


_WORKER: dict = {}   # in a --workers process: its env and policy


def _start_worker(eid: str, env_kwargs: dict, make_kwargs: dict, speed: float) -> None:
    import signal

    import surrol_data.envs  # noqa: F401  (registers the ids)

    # Ctrl-C reaches the whole process group: the recording process alone decides what is kept and stops the workers
    # (a worker killed by it mid-rollout would turn the user's Ctrl-C into a BrokenProcessPool traceback).
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    env = make_env(eid, env_kwargs, **make_kwargs)
    _WORKER.update(env=env, policy=ORACLE if speed == 1.0 else PacedOracle(env, speed))


def _roll_in_worker(seed: int) -> tuple:
    """(trajectory, seconds) of one seed, in a --workers process."""
    t0 = time.perf_counter()
    traj = rollout(_WORKER["env"], _WORKER["policy"], seed)
    return traj, time.perf_counter() - t0


ROLLOUTS_AHEAD = 64   # state-only rollouts asked of the workers before the recorder takes their results

# The script pace that matches the paper's script demos (NeedlePick, 150-step horizon: 109 steps, 11.7 cm).
SCRIPT_SPEED_MATCHED = 0.3


def collect_script(task: str, episodes: int, out: str | Path, seed: int | None = 0, max_steps: int | None = None,
                   keep_failures: bool = False, append: bool = False, max_attempts: int | None = None,
                   progress: bool = True, command: str | None = None,
                   camera_size: tuple[int, int] | None = None, speed: float = 1.0,
                   seed_stride: int = 1, workers: int = 0,
                   camera_renderer: str = DEFAULT_CAMERA_RENDERER) -> CollectResult:
    """Record ``episodes`` oracle episodes of ``task`` into the LeRobot dataset at ``out``.

    Attempt ``i`` uses seed ``seed + i * seed_stride`` (``seed=None``: 0, or with ``append`` the seed after the
    dataset's last scripted one, see :func:`first_seed`; a stride of N with first seeds 0..N-1 gives N collections
    disjoint seeds, :mod:`surrol_data.collect.shards`); an attempt is kept when it succeeded at some step (the original
    generator's rule), or always with ``keep_failures``. Gives up after ``max_attempts`` (default 3×).
    ``camera_size`` = (width, height) also records the endoscope view as video, drawn by ``camera_renderer``
    (recorded in the sidecar; every worker draws with it too).
    ``speed`` < 1 runs the oracle at that fraction of its pace (:class:`PacedOracle`; recorded in provenance).
    ``workers=0`` rolls the episodes out in this process; ``workers`` ≥ 1 in that many spawned processes while this
    one records them, in seed order: the same dataset whatever the number
    (:func:`surrol_data.collect.parallel_rollouts.ordered_rollouts`). One worker already overlaps the rollouts
    with the recording (writing, lerobot's import, the dataset's creation): ``collect``'s default. Spawned
    processes import the caller's ``__main__``: a script that sets ``workers`` needs the
    ``if __name__ == "__main__":`` guard.
    """
    if episodes <= 0:
        raise ValueError(f"the number of episodes must be positive, got {episodes}")
    if seed_stride < 1:
        raise ValueError(f"the seed stride must be at least 1, got {seed_stride}")
    if workers < 0:
        raise ValueError(f"the number of workers must be 0 (this process) or more, got {workers}")
    seed = first_seed(out, append, seed, "script")
    import surrol_data.envs  # noqa: F401  (registers the ids)

    eid = make_env_id(task)
    kwargs = {"max_episode_steps": max_steps} if max_steps else {}
    env_kwargs = camera_kwargs(camera_size, camera_renderer)
    env = make_env(eid, env_kwargs, **kwargs)
    task_name = eid.split("/")[1].rsplit("-v", 1)[0]
    result = CollectResult(root=Path(out))
    max_attempts = max_attempts or 3 * episodes
    policy = ORACLE if speed == 1.0 else PacedOracle(env, speed)
    settings = json.dumps({"oracle_speed": float(speed)}) if speed != 1.0 else "{}"
    recorder = DatasetRecorder(out, task=task_name, env_id=eid, task_description=env.unwrapped.TASK,
                               features=features_for(env), append=append, command=command,
                               robot_type=dimension_names(env).robot_type, camera_renderer=camera_renderer)
    bar = tqdm(total=episodes, desc=f"collect {task_name} (script)", unit="ep", disable=not progress)
    seeds = (seed + i * seed_stride for i in range(max_attempts))
    if workers >= 1:
        from surrol_data.collect.parallel_rollouts import ordered_rollouts

        # A state-only episode is small: the workers may run far ahead of a recorder that is creating its dataset
        # (MAX_UNSAVED_WHILE_IMPORTING episodes at once, ~1 s); camera episodes (MBs each) stay close.
        stream = ordered_rollouts(_start_worker, (eid, env_kwargs, kwargs, speed), _roll_in_worker,
                                  seeds, workers, ahead=ROLLOUTS_AHEAD if camera_size is None else 0)
    else:
        stream = _rollouts_here(env, policy, seeds)
    try:
        with recorder:
            for s, traj, duration in stream:
                result.attempts += 1
                if not traj.is_success:
                    result.failures += 1
                    if not keep_failures:
                        continue
                recorder.record(traj, {
                    "source": "script", "device": "none", "operator_id": "oracle", "skill": "scripted",
                    "operator_simulated": False, "operator_params": "{}", "device_settings": settings,
                    "seed": s, "duration_s": duration,
                })
                result.kept += 1
                result.seeds.append(s)
                if workers >= 1 and result.kept == 1:
                    # From here on this process mostly waits for the workers' episodes: lerobot's import runs
                    # meanwhile, and the recorder creates the dataset once it is done (episodes journalled till then).
                    recorder.import_lerobot_in_background()
                bar.update(1)
                bar.set_postfix(success=f"{result.success_rate:.2f}", refresh=False)
                if result.kept >= episodes:
                    break
    finally:
        stream.close()   # stops the worker processes, if any
        bar.close()
        env.close()
    if result.kept < episodes:
        raise RuntimeError(f"only {result.kept} of {episodes} oracle episodes of {task_name} succeeded in "
                           f"{result.attempts} attempts (kept episodes are saved in {out}); "
                           "use --keep-failures to record failures too")
    return result



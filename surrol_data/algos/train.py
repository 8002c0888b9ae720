"""The run loop: offline BC pre-training, then online learning in epochs, with evaluation, logs and exact resume.

A run reads top to bottom in :func:`train`:

1. build the learner (DDPG(+BC) or SAC), the agent replay buffer and the demo buffer; demos go into both
   buffers (reference §7.3) and into the normaliser statistics, HER-relabelled (§7.2);
2. offline phase: ``offline_steps`` BC steps of the actor on demo batches, then an "epoch 0" evaluation —
   for ``algo=bc`` this phase *is* the run (``offline_steps`` per epoch, no env interaction);
3. online phase, one epoch = ``cycles`` × (collect ``episodes_per_cycle`` episodes with the vector env,
   store them, update the normalisers, then ``updates_per_cycle`` learner updates); the first
   ``warmup_steps`` env steps use uniform random actions and no updates (DEX's seed steps);
4. after every epoch: deterministic evaluation on fixed seeds through :mod:`surrol_data.evaluation`
   (success, steps to complete, economy of motion), one row appended to ``metrics.jsonl``/``metrics.csv``
   and TensorBoard, then a checkpoint (written atomically) and the current ``policy.pt``.
   ``process.json`` records the pid and start/finish times (sweeps are checked to run in parallel with it).

Exact resume: the checkpoint holds every piece of state that the future depends on — weights, optimisers,
normalisers, both buffers, every random generator, counters and the metrics so far — and training episodes
are seeded from the episode counter, so a run killed at any point and restarted with ``resume=True``
produces the same rows as one that never stopped (on one torch thread; wall times differ, of course).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

from surrol_data.algos.ddpg import DDPG, DDPGConfig
from surrol_data.algos.demos import DemoSpec, load_demos
from surrol_data.algos.replay import EpisodeReplay, rng_from_tensor, rng_state_tensor
from surrol_data.algos.sac import SAC, SACConfig
from surrol_data.algos.warm_probe import probe, probe_states
from surrol_data.evaluation.metrics import summarize, trajectory_proficiency
from surrol_data.evaluation.rollout import EVAL_SEED_BASE, rollout

CHECKPOINT_FORMAT = "surrol_data.train/1"
LEARNERS = {"ddpg": (DDPG, DDPGConfig), "sac": (SAC, SACConfig)}
TRAIN_SEED_STRIDE = 1_000_000    # run seed s trains on episode seeds s·stride, s·stride + 1, …


@dataclass
class Schedule:
    """What an epoch is. Reference protocol: 20 cycles × 2 episodes × 50 steps, 40 updates per cycle."""
    epochs: int = 50
    cycles: int = 20
    episodes_per_cycle: int = 2
    updates_per_cycle: int = 40
    max_episode_steps: int = 50
    eval_episodes: int = 20
    n_envs: int = 2                 # env worker processes (1 = in-process)
    warmup_steps: int = 0           # first env steps: uniform random actions, no updates
    offline_steps: int = 0          # BC steps before the online phase (per epoch when online is false)
    online: bool = True             # false: offline BC only (algo=bc)
    buffer_episodes: int = 2000
    her_k: int = 4
    demos_in_replay: bool = True    # also put the demos in the agent replay buffer (DEX)
    torch_threads: int = 1


@dataclass
class TrainConfig:
    env_id: str
    run_dir: str
    learner: str = "ddpg"
    learner_params: dict = field(default_factory=dict)
    demos: DemoSpec = field(default_factory=DemoSpec)
    schedule: Schedule = field(default_factory=Schedule)
    seed: int = 0
    resume: bool = False
    overwrite: bool = False         # replace the outputs of an earlier run in run_dir (else it is refused)
    progress: bool = True
    tensorboard: bool = True


def make_env(env_id: str, max_episode_steps: int) -> gym.Env:
    import surrol_data.envs  # noqa: F401  (registers the ids, also inside spawned workers)

    return gym.make(env_id, max_episode_steps=max_episode_steps)


def make_vector_env(env_id: str, max_episode_steps: int, n_envs: int) -> gym.vector.VectorEnv:
    fns = [partial(make_env, env_id, max_episode_steps) for _ in range(n_envs)]
    if n_envs == 1:
        return gym.vector.SyncVectorEnv(fns)
    # spawn, not fork: the parent already runs torch's thread pool, which a forked child must not inherit
    return gym.vector.AsyncVectorEnv(fns, context="spawn")


def build_learner(cfg: TrainConfig, obs_dim: int, goal_dim: int, act_dim: int) -> DDPG | SAC:
    if cfg.learner not in LEARNERS:
        raise ValueError(f"unknown learner {cfg.learner!r}; choose one of {sorted(LEARNERS)}")
    cls, config_cls = LEARNERS[cfg.learner]
    params = dict(cfg.learner_params)
    unknown = set(params) - set(config_cls.__dataclass_fields__)
    if unknown:
        raise ValueError(f"{cfg.learner}: unknown parameter(s) {sorted(unknown)}; "
                         f"known: {sorted(config_cls.__dataclass_fields__)}")
    if "hidden_sizes" in params:
        params["hidden_sizes"] = tuple(int(h) for h in params["hidden_sizes"])
    return cls(obs_dim, goal_dim, act_dim, config_cls(**params), seed=cfg.seed)


def _check(cfg: TrainConfig) -> None:
    s = cfg.schedule
    if s.episodes_per_cycle % s.n_envs:
        raise ValueError(f"episodes_per_cycle ({s.episodes_per_cycle}) must be a multiple of n_envs ({s.n_envs}): "
                         "each collection step runs one episode in every env")
    if min(s.epochs, s.max_episode_steps, s.eval_episodes, s.n_envs, s.buffer_episodes, s.torch_threads) < 1:
        raise ValueError(f"epochs, max_episode_steps, eval_episodes, n_envs, buffer_episodes and torch_threads "
                         f"must be >= 1: {s}")
    if not s.online and s.offline_steps < 1:
        raise ValueError("an offline-only run (online=false) needs offline_steps >= 1 per epoch")
    if not s.online and cfg.demos.path is None:
        raise ValueError("offline BC needs demos: pick demos=script|expert|novice, not demos=none")


class RunLog:
    """metrics.jsonl + metrics.csv (what the report reads) and TensorBoard, one row per epoch."""

    def __init__(self, run_dir: Path, rows: list[dict], tensorboard: bool):
        self.run_dir, self.rows = run_dir, rows
        if tensorboard:   # before any file is written: a start that fails here leaves nothing that refuses a rerun
            from surrol_data.extras import require

            require("tensorboard")   # torch's SummaryWriter needs it; a clear message names the extra
        self._rewrite()  # after a resume: drop any row written after the checkpoint that was restored
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=(rows[-1]["epoch"] + 1) if rows else None)

    def append(self, row: dict) -> None:
        self.rows.append(row)
        with open(self.run_dir / "metrics.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        self._write_csv()
        if self.writer is not None:
            for key, value in row.items():
                if key != "epoch" and isinstance(value, (int, float)) and math.isfinite(value):
                    self.writer.add_scalar(key, value, row["epoch"])
            self.writer.flush()

    def _rewrite(self) -> None:
        with open(self.run_dir / "metrics.jsonl", "w") as f:
            f.writelines(json.dumps(r) + "\n" for r in self.rows)
        self._write_csv()

    def _write_csv(self) -> None:
        keys = list(dict.fromkeys(k for r in self.rows for k in r))
        with open(self.run_dir / "metrics.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            w.writerows(self.rows)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def read_metrics(run_dir: str | Path) -> list[dict]:
    """The per-epoch rows of a run (``metrics.jsonl``)."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"no metrics.jsonl in {run_dir}: is it a training run folder?")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def evaluate_policy(env: gym.Env, policy, episodes: int) -> dict:
    """Deterministic rollouts on fixed seeds, scored by the proficiency metrics that score human demos."""
    scores = [trajectory_proficiency(rollout(env, policy, EVAL_SEED_BASE + i)) for i in range(episodes)]
    s = summarize(scores)
    # success = flag at the last step (DEX/baselines); the any-time rate is kept beside it
    return {"success_rate": s["final_success_rate"], "any_success_rate": s["success_rate"],
            "steps_to_complete": s["mean_steps_to_success"], "economy_of_motion_cm": s["mean_path_length_cm"]}


# How a run was launched, not what it computes: a resume may differ in them (a run begun with overwrite=true is
# resumed with resume=true alone)
LAUNCH_SETTINGS = ("resume", "overwrite", "progress", "tensorboard")
RUN_OUTPUTS = ("checkpoint.pt", "metrics.jsonl", "metrics.csv", "policy.pt", "config.json", "process.json", "tb")


def claim_run_dir(run_dir: Path, *, resume: bool, overwrite: bool) -> None:
    """Make ``run_dir``; an earlier run's outputs there are refused unless resumed or overwritten."""
    if resume and overwrite:
        raise ValueError("resume=true and overwrite=true contradict each other: pick one")
    found = [name for name in RUN_OUTPUTS if (run_dir / name).exists()]
    if found and not resume:
        if not overwrite:
            raise FileExistsError(f"{run_dir} already holds a run ({', '.join(found)}): pass resume=true to continue "
                                  "it, overwrite=true to replace it, or choose another run_dir")
        for name in found:
            path = run_dir / name
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    run_dir.mkdir(parents=True, exist_ok=True)


def train(cfg: TrainConfig) -> list[dict]:
    """Run (or resume) training; returns the per-epoch metric rows."""
    _check(cfg)
    s = cfg.schedule
    run_dir = Path(cfg.run_dir)
    claim_run_dir(run_dir, resume=cfg.resume, overwrite=cfg.overwrite)
    ckpt_path = run_dir / "checkpoint.pt"
    torch.set_num_threads(s.torch_threads)

    # 1. env spaces, learner, buffers, demos
    eval_env = make_env(cfg.env_id, s.max_episode_steps)
    spaces = eval_env.observation_space
    obs_dim, goal_dim = spaces["observation"].shape[0], spaces["desired_goal"].shape[0]
    act_dim = eval_env.action_space.shape[0]
    learner = build_learner(cfg, obs_dim, goal_dim, act_dim)
    reward_fn = eval_env.unwrapped.compute_reward
    replay = EpisodeReplay(s.buffer_episodes, s.max_episode_steps, obs_dim, goal_dim, act_dim,
                           reward_fn, s.her_k, seed=cfg.seed)
    demo_trajs, demo_eps = load_demos(cfg.demos, cfg.env_id)
    demo_buffer = None
    if demo_trajs:
        demo_buffer = EpisodeReplay(len(demo_trajs), s.max_episode_steps, obs_dim, goal_dim, act_dim,
                                    reward_fn, s.her_k, seed=cfg.seed + 1)
    collect_rng = np.random.default_rng([cfg.seed, 7])  # warm-up random actions

    state = {"epoch": 0, "env_steps": 0, "episodes": 0, "updates": 0, "wall_s": 0.0}
    rows: list[dict] = []
    if cfg.resume and ckpt_path.is_file():
        ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        if ckpt.get("format") != CHECKPOINT_FORMAT:
            raise ValueError(f"{ckpt_path} is not a training checkpoint (format {ckpt.get('format')!r})")
        saved = json.loads(ckpt["config"])
        if {k: v for k, v in saved.items() if k not in LAUNCH_SETTINGS} != \
                {k: v for k, v in _config_json(cfg).items() if k not in LAUNCH_SETTINGS}:
            raise ValueError(f"{ckpt_path} was written by a run with another configuration; resume with the same "
                             f"overrides, or start a new run folder. Saved: {saved}")
        learner.load_state_dict(ckpt["learner"])
        replay.load_state_dict(ckpt["replay"])
        if demo_buffer is not None:
            demo_buffer.load_state_dict(ckpt["demo_buffer"])
        collect_rng = rng_from_tensor(ckpt["collect_rng"])
        state, rows = dict(ckpt["state"]), json.loads(ckpt["rows"])
        print(f"resumed {run_dir} after epoch {state['epoch']} ({state['env_steps']} env steps)")
    else:
        for traj in demo_trajs:
            episode = (traj.observation, traj.achieved_goal, traj.desired_goal[:-1], traj.action)
            slot = demo_buffer.add_episode(*episode)
            learner.inputs.update(*demo_buffer.sample_episode_for_stats(slot))
            if s.demos_in_replay and s.online:
                replay.add_episode(*episode)
    # offline→online diagnostics (algo.params.probe=true): fixed demo states, probed after every epoch
    probe_set = probe_states(demo_trajs) if demo_trajs and getattr(learner.config, "probe", False) else None
    log = RunLog(run_dir, rows, cfg.tensorboard)
    process = {"pid": os.getpid(), "started": time.time(), "resumed_after_epoch": state["epoch"] if rows else None}
    _write_json(run_dir / "process.json", process)
    (run_dir / "config.json").write_text(json.dumps({**_config_json(cfg), "demo_episodes": demo_eps}, indent=2))

    def finish_epoch(extra: dict, started: float) -> None:
        policy = learner.policy()
        t_eval = time.perf_counter()
        row = {"epoch": state["epoch"], "env_steps": state["env_steps"], "episodes": state["episodes"],
               "updates": state["updates"], **evaluate_policy(eval_env, policy, s.eval_episodes), **extra}
        row["time_eval_s"] = round(time.perf_counter() - t_eval, 3)
        if probe_set is not None and s.online:
            row.update(probe(learner, *probe_set))
        state["wall_s"] += time.perf_counter() - started  # the epoch's collection, updates and evaluation
        row["wall_s"] = round(state["wall_s"], 3)
        with _stop_signals_held():
            log.append(row)
            policy.save(run_dir / "policy.pt")
            _save_checkpoint(ckpt_path, cfg, learner, replay, demo_buffer, collect_rng, state, log.rows)

    venv = None
    bar = tqdm(total=s.epochs, initial=state["epoch"], desc=f"train {cfg.env_id.split('/')[-1]}",
               unit="epoch", disable=not cfg.progress)
    if cfg.progress and state["epoch"] < s.epochs:
        tqdm.write(what_to_expect(cfg, state["epoch"]), file=sys.stderr)
    timed_epoch = None   # the first epoch this process trains in full: its time foretells the rest
    try:
        # 2. offline phase (epoch 0): BC pre-training of the actor, unless a resumed run already did it
        if not log.rows and s.online:
            t0 = time.perf_counter()
            losses = [learner.pretrain_step(demo_buffer) for _ in range(s.offline_steps)] if demo_buffer else []
            learner.finish_pretraining()
            extra = {"bc_loss": float(np.mean(losses)) if losses else float("nan")}
            critic_steps = getattr(learner.config, "critic_pretrain_steps", 0) if demo_buffer else 0
            if critic_steps:  # offline→online warm start: the critic learns the pre-trained actor's values
                critic_losses = [learner.pretrain_critic_step(demo_buffer) for _ in range(critic_steps)]
                extra["critic_pretrain_loss"] = float(np.mean(critic_losses[-100:]))
            finish_epoch(extra, t0)

        # 3. epochs
        if s.online:
            venv = make_vector_env(cfg.env_id, s.max_episode_steps, s.n_envs)
        while state["epoch"] < s.epochs:
            t0 = time.perf_counter()
            state["epoch"] += 1
            if not s.online:
                losses = [learner.pretrain_step(demo_buffer) for _ in range(s.offline_steps)]
                extra = {"bc_loss": float(np.mean(losses))}
            else:
                extra = _online_epoch(cfg, learner, venv, replay, demo_buffer, collect_rng, state)
            finish_epoch(extra, t0)
            if timed_epoch is None and cfg.progress and state["epoch"] < s.epochs:
                timed_epoch = state["epoch"]
                tqdm.write(time_left(log.rows[-1], time.perf_counter() - t0, s.epochs - state["epoch"]),
                           file=sys.stderr)
            bar.update(1)
            bar.set_postfix(success=f"{log.rows[-1]['success_rate']:.2f}", steps=state["env_steps"], refresh=False)
    except BaseException:
        stopped = True   # Ctrl-C, SIGTERM or an error: the epoch under way is dropped (the last checkpoint stands)
        raise
    else:
        stopped = False
    finally:
        bar.close()
        log.close()
        _write_json(run_dir / "process.json", {**process, "finished": time.time(), "epochs_done": state["epoch"]})
        eval_env.close()
        if venv is not None:
            # A stopped run ends its env workers rather than asking them to close: one may be mid-step, or gone (a
            # signal to the whole process group), and its answer would be waited for forever.
            venv.close(terminate=stopped)
    return log.rows


# The reference protocol (20 cycles × 2 episodes × 50 steps, 800 updates, 20 evaluation episodes) on NeedlePick
# with ddpgbc took 38–96 s an epoch on a shared 2-core CPU: the start-up estimate scales it by an epoch's env steps.
REFERENCE_EPOCH_S = (38.0, 96.0)
REFERENCE_EPOCH_STEPS = 20 * 2 * 50 + 20 * 50


def what_to_expect(cfg: TrainConfig, done: int) -> str:
    """What the epochs of a run are, about how long each takes before one is measured, and how early ones look."""
    s = cfg.schedule
    left = s.epochs - done
    if not s.online:
        return (f"{left} epoch(s) to go, each {s.offline_steps:,} BC steps and {s.eval_episodes} evaluation episodes; "
                "every epoch is checkpointed (Ctrl-C, then resume=true)")
    episodes = s.cycles * s.episodes_per_cycle
    steps = episodes * s.max_episode_steps
    scale = (steps + s.eval_episodes * s.max_episode_steps) / REFERENCE_EPOCH_STEPS
    low, high = (scale * t for t in REFERENCE_EPOCH_S)
    return (f"{left} epoch(s) to go, each {episodes} episodes ({steps:,} env steps in {s.n_envs} env process(es)), "
            f"{s.cycles * s.updates_per_cycle:,} updates and {s.eval_episodes} evaluation episodes: about "
            f"{_duration(low)}–{_duration(high)} an epoch on a 2-core CPU, {_duration(left * low)}–"
            f"{_duration(left * high)} in all (measured after the first epoch). Success often stays at 0 for the "
            "first epochs (with demos it may first fall from its BC level) while the critic learns, then climbs; "
            "every epoch is checkpointed (Ctrl-C, then resume=true)")


def time_left(row: dict, epoch_s: float, left: int) -> str:
    """The measured time of the epoch of ``row`` and what it foretells for the ``left`` epochs to go."""
    parts = [f"{name} {row[key]:.0f} s" for name, key in (("collect", "time_collect_s"), ("updates", "time_update_s"),
                                                           ("evaluation", "time_eval_s")) if key in row]
    return (f"epoch {row['epoch']} took {_duration(epoch_s)}" + (f" ({', '.join(parts)})" if parts else "")
            + f": the {left} left take about {_duration(left * epoch_s)}")


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _online_epoch(cfg: TrainConfig, learner, venv, replay: EpisodeReplay, demo_buffer: EpisodeReplay | None,
                  collect_rng: np.random.Generator, state: dict) -> dict:
    s = cfg.schedule
    train_success, metrics = [], []
    collect_s = update_s = 0.0
    for _ in range(s.cycles):
        t0 = time.perf_counter()
        for _ in range(s.episodes_per_cycle // s.n_envs):
            seeds = [cfg.seed * TRAIN_SEED_STRIDE + state["episodes"] + i for i in range(s.n_envs)]
            random_actions = state["env_steps"] < s.warmup_steps
            obs_list, ag_list, g_list, act_list = _collect(venv, learner, seeds, s.max_episode_steps,
                                                           random_actions, collect_rng, train_success)
            for i in range(s.n_envs):
                slot = replay.add_episode(obs_list[:, i], ag_list[:, i], g_list[:, i], act_list[:, i])
                learner.inputs.update(*replay.sample_episode_for_stats(slot))
            state["episodes"] += s.n_envs
            state["env_steps"] += s.n_envs * s.max_episode_steps
        t1 = time.perf_counter()
        collect_s += t1 - t0
        if state["env_steps"] >= s.warmup_steps:
            for _ in range(s.updates_per_cycle):
                metrics.append(learner.update(replay, demo_buffer))
            state["updates"] += s.updates_per_cycle
        update_s += time.perf_counter() - t1
    # timings are the only row entries that differ between a resumed run and an uninterrupted one
    out = {"train_success_rate": float(np.mean(train_success)),
           "time_collect_s": round(collect_s, 3), "time_update_s": round(update_s, 3)}
    for key in (metrics[0] if metrics else {}):
        out[key] = float(np.mean([m[key] for m in metrics if key in m]))
    return out


def _collect(venv, learner, seeds: list[int], steps: int, random_actions: bool, rng: np.random.Generator,
             success_out: list) -> tuple[np.ndarray, ...]:
    """One episode in each env; arrays shaped (time, env, dim)."""
    obs, _ = venv.reset(seed=seeds)
    o, ag, g, acts = [obs["observation"]], [obs["achieved_goal"]], [], []
    info = {}
    for _ in range(steps):
        if random_actions:
            action = rng.uniform(-1.0, 1.0, (len(seeds), venv.single_action_space.shape[0])).astype(np.float32)
        else:
            action = learner.act(obs, explore=True)
        g.append(obs["desired_goal"])
        obs, _, _, _, info = venv.step(action)
        o.append(obs["observation"])
        ag.append(obs["achieved_goal"])
        acts.append(action)
    success_out.extend(np.asarray(info["is_success"], float).tolist())
    return np.stack(o), np.stack(ag), np.stack(g), np.stack(acts)


@contextlib.contextmanager
def _stop_signals_held():
    """Ctrl-C or SIGTERM while an epoch's row, policy and checkpoint are written takes effect once they are: the
    last epoch the metrics show is the one a resume starts after (a stop in between kept the row, lost the
    checkpoint). Signals reach the main thread only; elsewhere nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    replaced = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(signum)
        if handler not in (signal.SIG_IGN, None):
            replaced[signum] = handler
            signal.signal(signum, lambda n, frame: held.append(n))
    try:
        yield
    finally:
        for signum, handler in replaced.items():
            signal.signal(signum, handler)
        if held:
            signal.raise_signal(held[0])   # now, to the handler it was meant for


def _write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2))


def _config_json(cfg: TrainConfig) -> dict:
    config = json.loads(json.dumps(asdict(cfg), default=str))
    # demos.frames came after runs were recorded: at its default (every frame) it stays out, so the record, the
    # resume check and the study's configs of those runs read as they always did.
    if config["demos"].get("frames") == "all":
        del config["demos"]["frames"]
    return config


def _save_checkpoint(path: Path, cfg: TrainConfig, learner, replay: EpisodeReplay, demo_buffer: EpisodeReplay | None,
                     collect_rng: np.random.Generator, state: dict, rows: list[dict]) -> None:
    ckpt = {"format": CHECKPOINT_FORMAT, "config": json.dumps(_config_json(cfg)), "state": dict(state),
            "rows": json.dumps(rows), "learner": learner.state_dict(), "replay": replay.state_dict(),
            "collect_rng": rng_state_tensor(collect_rng)}
    if demo_buffer is not None:
        ckpt["demo_buffer"] = demo_buffer.state_dict()
    tmp = path.with_suffix(".tmp")
    torch.save(ckpt, tmp)
    os.replace(tmp, path)  # atomic: a kill mid-write leaves the previous checkpoint intact

"""Several DDPG(+BC)+HER runs (seeds, demo sources) trained in one process as one batched ensemble.

The same run as :func:`surrol_data.algos.train.train`, for M runs at once, read top to bottom in
:func:`train_batched`:

1. one :class:`~surrol_data.algos.ensemble.EnsembleDDPG` holds the M members' networks stacked; every member
   keeps its own replay and demo buffers, normalisers, generators, run folder, ``metrics.jsonl`` and
   ``checkpoint.pt`` — the checkpoint is the single run's format, written from the member's slice;
2. offline phase: BC pre-training of all actors in one batched step each (and the optional critic warm-up);
3. online epochs: every cycle collects every member's ``episodes_per_cycle`` episodes at once in an
   :class:`~surrol_data.algos.env_pool.EnvPool` (M × episodes_per_cycle envs on ``n_workers`` processes). The
   workers play whole episodes on their own, from a snapshot of the actors and the exploration noise drawn
   here from each member's generator, so there is no round trip per env step. With ``overlap`` the previous
   cycle's updates run in this process *while the workers play*, so the two cores are busy with envs and
   updates at the same time; the cost is a policy one cycle staler than the serial schedule's (off-policy
   learning does not care) — ``overlap=False`` gives the serial schedule;
4. evaluation of all members through the same pool, deterministic, on the single run's evaluation seeds,
   scored by the same proficiency metrics; then per member one metrics row and one checkpoint.

A member's training episodes use the single run's seeds (``seed·1e6 + episode``) and the member draws its
batches and exploration noise from its own generator in the single run's order (with ``overlap`` a cycle's
noise is drawn before, not after, the previous cycle's batches), so a member reproduces the single run up to
floating-point rounding of the batched kernels (and, with ``overlap``, the policy lag and that draw order).

Exact resume after SIGKILL: member checkpoints are written to temporary files first and then moved into
place one by one, keeping the one they replace as ``checkpoint.prev.pt``; a kill between two moves leaves
some members one epoch ahead, and a resume loads every member at the oldest epoch found (from ``.prev``
where needed), so all members restart together from one consistent epoch.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from surrol_data.algos.ddpg import DDPGConfig
from surrol_data.algos.demos import load_demos
from surrol_data.algos.ensemble import EnsembleDDPG
from surrol_data.algos.env_pool import EnvPool
from surrol_data.algos.heap import release_free_heap
from surrol_data.algos.learner_threads import LearnerThreads
from surrol_data.algos.replay import EpisodeReplay, rng_from_tensor, rng_state_tensor
from surrol_data.algos.train import (CHECKPOINT_FORMAT, EVAL_SEED_BASE, LAUNCH_SETTINGS, TRAIN_SEED_STRIDE, RunLog,
                                     TrainConfig, _check, _config_json, _write_json, claim_run_dir, make_env)
from surrol_data.datasets.trajectory import Trajectory
from surrol_data.evaluation.episode_rows import episode_row
from surrol_data.evaluation.metrics import summarize, trajectory_proficiency

PREV = "checkpoint.prev.pt"
ACTORS_DIR = "actors"   # the actor at chosen epochs (train_batched's actor_epochs), for evaluating them again


def actor_path(run_dir: str | Path, epoch: int) -> Path:
    """Where a run keeps its actor of ``epoch`` (a :class:`~surrol_data.algos.bc.BCPolicy`, like ``policy.pt``)."""
    return Path(run_dir) / ACTORS_DIR / f"epoch{int(epoch):03d}.pt"


EPISODES_FILE = "eval_episodes.csv"


def _write_episode_rows(run_dir: Path, epoch: int, rows: list[dict]) -> None:
    """Add (or, after a resume, replace) the epoch's per-episode evaluation rows in ``eval_episodes.csv``."""
    import pandas as pd

    path = run_dir / EPISODES_FILE
    new = pd.DataFrame([{"epoch": epoch, **r} for r in rows])
    if path.is_file():
        old = pd.read_csv(path)
        new = pd.concat([old[old["epoch"] != epoch], new], ignore_index=True)
    tmp = path.with_suffix(".tmp")
    new.to_csv(tmp, index=False)
    os.replace(tmp, path)


def _check_members(cfgs: list[TrainConfig]) -> None:
    if not cfgs:
        raise ValueError("train_batched needs at least one run configuration")
    first = cfgs[0]
    for cfg in cfgs:
        _check(cfg)
        if cfg.learner != "ddpg":
            raise ValueError(f"the batched path trains DDPG-family algos (ddpgbc, ddpg, ddpgbc_warm), not "
                             f"learner {cfg.learner!r}; run it without batched=true")
        if (cfg.env_id, cfg.learner_params, cfg.schedule) != (first.env_id, first.learner_params, first.schedule):
            raise ValueError("all runs of one batched ensemble must share task, algo and experiment; only seed "
                             f"and demos may differ ({cfg.run_dir} differs from {first.run_dir})")
        if (cfg.demos.path is None) != (first.demos.path is None):
            raise ValueError("a batched ensemble cannot mix runs with and without demos (demos=none)")
        if not cfg.schedule.online:
            raise ValueError("the batched path is for online runs; algo=bc trains offline in seconds anyway")
    dirs = [str(Path(c.run_dir).resolve()) for c in cfgs]
    if len(set(dirs)) != len(dirs):
        raise ValueError(f"two runs of the ensemble write to the same run_dir: {dirs}; put ${{seed}} and "
                         "${demos.name} in run_dir")


def _learner_config(cfg: TrainConfig) -> DDPGConfig:
    params = dict(cfg.learner_params)
    params.pop("probe", None)  # warm_probe's diagnostic columns are a single-run feature; training is the same
    unknown = set(params) - set(DDPGConfig.__dataclass_fields__)
    if unknown:
        raise ValueError(f"ddpg: unknown parameter(s) {sorted(unknown)}; known: {sorted(DDPGConfig.__dataclass_fields__)}")
    if "hidden_sizes" in params:
        params["hidden_sizes"] = tuple(int(h) for h in params["hidden_sizes"])
    return DDPGConfig(**params)


class _Member:
    """What one run of the ensemble owns besides its slice of the networks."""

    def __init__(self, cfg: TrainConfig, replay: EpisodeReplay, demo_buffer: EpisodeReplay | None, demo_eps: list):
        self.cfg, self.replay, self.demo_buffer, self.demo_eps = cfg, replay, demo_buffer, demo_eps
        self.run_dir = Path(cfg.run_dir)
        self.collect_rng = np.random.default_rng([cfg.seed, 7])
        self.state = {"epoch": 0, "env_steps": 0, "episodes": 0, "updates": 0, "wall_s": 0.0}
        self.rows: list[dict] = []
        self.log: RunLog | None = None
        self.process: dict = {}


def train_batched(cfgs: list[TrainConfig], overlap: bool = True, n_workers: int = 2,
                  progress: bool = True, worker_nice: int = 0, widen_threads: bool = True,
                  episode_epochs: tuple[int, ...] = (), actor_epochs: tuple[int, ...] = ()) -> list[list[dict]]:
    """Train (or resume) the runs ``cfgs`` as one ensemble; returns every member's per-epoch rows.

    ``episode_epochs``: epochs whose evaluation episodes are also written one row each (success, steps, path,
    failed grasps, attempts, retries and the episode's attempt outcome: :mod:`surrol_data.datasets.attempts`) to
    ``eval_episodes.csv`` in every run folder. ``actor_epochs``: epochs whose actor every run keeps
    (:func:`actor_path`).

    ``widen_threads``: let the learner use the cores the workers leave idle when that is measured faster
    (:mod:`~surrol_data.algos.learner_threads`); False keeps it at ``torch_threads`` (the benchmark's baseline).

    ``worker_nice``: the env workers' niceness. While they play, the learner's updates are one thread the
    cycle waits for; with equal priority the scheduler gives it only its share of the cores (2/3 of one with
    two workers on two cores). Niced workers would leave it a whole core on a quiet machine, but on a shared
    one they lose to every other job: measured slower there (benchmarks/train_speed.py --worker-nice), so 0."""
    _check_members(cfgs)
    for cfg in cfgs:   # as single runs: an earlier run's folder is refused unless resumed or overwritten
        claim_run_dir(Path(cfg.run_dir), resume=cfg.resume, overwrite=cfg.overwrite)
    s, first = cfgs[0].schedule, cfgs[0]
    torch.set_num_threads(s.torch_threads)

    # 1. spaces, ensemble, per-member buffers and demos
    probe = make_env(first.env_id, s.max_episode_steps)
    spaces = probe.observation_space
    obs_dim, goal_dim = spaces["observation"].shape[0], spaces["desired_goal"].shape[0]
    act_dim = probe.action_space.shape[0]
    reward_fn = probe.unwrapped.compute_reward
    learner = EnsembleDDPG(obs_dim, goal_dim, act_dim, _learner_config(first), [c.seed for c in cfgs])
    members, demo_sets = [], {}
    for cfg in cfgs:
        replay = EpisodeReplay(s.buffer_episodes, s.max_episode_steps, obs_dim, goal_dim, act_dim, reward_fn,
                               s.her_k, seed=cfg.seed)
        key = json.dumps(_config_json(cfg)["demos"], sort_keys=True, default=str)
        if key not in demo_sets:  # the seeds of one demo source share its demo set: read it once
            demo_sets[key] = load_demos(cfg.demos, cfg.env_id)
        trajs, eps = demo_sets[key]
        demo_buffer = EpisodeReplay(len(trajs), s.max_episode_steps, obs_dim, goal_dim, act_dim, reward_fn,
                                    s.her_k, seed=cfg.seed + 1) if trajs else None
        member = _Member(cfg, replay, demo_buffer, eps)
        member.trajs = trajs
        members.append(member)
    resumed = _resume(members, learner)
    for i, m in enumerate(members):
        if not resumed:
            for traj in m.trajs:
                episode = (traj.observation, traj.achieved_goal, traj.desired_goal[:-1], traj.action)
                slot = m.demo_buffer.add_episode(*episode)
                learner.inputs[i].update(*m.demo_buffer.sample_episode_for_stats(slot))
                if s.demos_in_replay:
                    m.replay.add_episode(*episode)
        del m.trajs
        m.run_dir.mkdir(parents=True, exist_ok=True)
        m.log = RunLog(m.run_dir, m.rows, m.cfg.tensorboard)
        m.process = {"pid": os.getpid(), "started": time.time(), "batched_members": len(members),
                     "resumed_after_epoch": m.state["epoch"] if m.rows else None}
        _write_json(m.run_dir / "process.json", m.process)
        (m.run_dir / "config.json").write_text(json.dumps({**_config_json(m.cfg), "demo_episodes": m.demo_eps,
                                                           "batched_members": len(members)}, indent=2))
    probe.close()

    per_member_envs = s.episodes_per_cycle
    pool = EnvPool(first.env_id, s.max_episode_steps, len(members) * per_member_envs, n_workers, worker_nice)
    demo_buffers = [m.demo_buffer for m in members] if members[0].demo_buffer is not None else None
    replays = [m.replay for m in members]
    threads = LearnerThreads(s.torch_threads, pool.busy_workers, widen=widen_threads)

    cpu = {"learner": time.process_time(), "envs": pool.worker_cpu_seconds()}

    def finish_epoch(extras: list[dict], started: float) -> None:
        t_eval, envs_before_eval = time.perf_counter(), pool.worker_cpu_seconds()
        scores, episode_rows = _evaluate(pool, learner, s.eval_episodes, s.max_episode_steps, per_member_envs)
        eval_s = time.perf_counter() - t_eval
        eval_cpu = pool.worker_cpu_seconds() - envs_before_eval
        elapsed = time.perf_counter() - started
        # CPU seconds of this process (learner) and of the env workers in the epoch: with the wall time they
        # say how busy the cores were, which a wall clock on a shared machine cannot
        now = {"learner": time.process_time(), "envs": pool.worker_cpu_seconds()}
        used = {k: now[k] - cpu[k] for k in now}
        cpu.update(now)
        for i, m in enumerate(members):
            row = {"epoch": m.state["epoch"], "env_steps": m.state["env_steps"], "episodes": m.state["episodes"],
                   "updates": m.state["updates"], **scores[i], **extras[i]}
            row["time_eval_s"] = round(eval_s, 3)
            row["time_cpu_learner_s"] = round(used["learner"], 3)
            row["time_cpu_envs_s"] = round(used["envs"], 3)
            row["time_cpu_envs_eval_s"] = round(eval_cpu, 3)   # (of time_cpu_envs_s: the evaluation's share)
            m.state["wall_s"] += elapsed  # the ensemble's epoch: every member waited for all of it
            row["wall_s"] = round(m.state["wall_s"], 3)
            row["batched_members"] = len(members)   # the epoch's CPU seconds are the whole ensemble's
            m.log.append(row)
            if m.state["epoch"] in episode_epochs:   # per-episode records at the epochs a report reads closely
                _write_episode_rows(m.run_dir, m.state["epoch"], episode_rows[i])
            learner.policy(i).save(m.run_dir / "policy.pt")
            if m.state["epoch"] in actor_epochs:
                actor_path(m.run_dir, m.state["epoch"]).parent.mkdir(exist_ok=True)
                learner.policy(i).save(actor_path(m.run_dir, m.state["epoch"]))
        # the checkpoints' contents are taken now; writing them (hundreds of MB once the buffers fill) waits
        # for the next epoch's first rollout, when the learner has no updates to run
        pending_save.append(_checkpoints(members, learner))

    pending_save: list[list[dict]] = []

    def write_checkpoints() -> None:
        if not pending_save:
            return
        while pending_save:
            _write_checkpoints(members, pending_save.pop(0))
        release_free_heap()   # the epoch's freed copies: without this the process grew by GBs (algos/heap.py)

    bar = tqdm(total=s.epochs, initial=members[0].state["epoch"], unit="epoch", disable=not progress,
               desc=f"train {len(members)} runs {first.env_id.split('/')[-1]}")
    try:
        # 2. offline phase (epoch 0)
        if not members[0].rows:
            t0 = time.perf_counter()
            # its own timings: a BC step is cheaper than an update
            bc_threads = LearnerThreads(s.torch_threads, pool.busy_workers, widen=widen_threads)
            losses = [bc_threads.timed(learner.pretrain_step, demo_buffers) for _ in range(s.offline_steps)] \
                if demo_buffers else []
            learner.finish_pretraining()
            critic_losses = [learner.pretrain_critic_step(demo_buffers)
                             for _ in range(learner.config.critic_pretrain_steps)] if demo_buffers else []
            extras = []
            for i in range(len(members)):
                extra = {"bc_loss": float(np.mean([step[i] for step in losses])) if losses else float("nan")}
                if critic_losses:
                    extra["critic_pretrain_loss"] = float(np.mean([step[i] for step in critic_losses[-100:]]))
                extras.append(extra)
            finish_epoch(extras, t0)

        # 3. epochs
        while members[0].state["epoch"] < s.epochs:
            t0 = time.perf_counter()
            for m in members:
                m.state["epoch"] += 1
            extras = _online_epoch(members, learner, pool, replays, demo_buffers, overlap, write_checkpoints,
                                   threads)
            finish_epoch(extras, t0)
            bar.update(1)
            bar.set_postfix(success=" ".join(f"{m.rows[-1]['success_rate']:.2f}" for m in members), refresh=False)
        write_checkpoints()
    finally:
        write_checkpoints()   # an interrupted epoch leaves the last finished one's checkpoints, complete
        torch.set_num_threads(s.torch_threads)
        bar.close()
        pool.close()
        for m in members:
            if m.log is not None:
                m.log.close()
            _write_json(m.run_dir / "process.json", {**m.process, "finished": time.time(),
                                                     "epochs_done": m.state["epoch"]})
    return [m.log.rows for m in members]


def _online_epoch(members: list[_Member], learner: EnsembleDDPG, pool: EnvPool, replays, demo_buffers,
                  overlap: bool, while_first_rollout, threads: LearnerThreads) -> list[dict]:
    s = members[0].cfg.schedule
    per_member = s.episodes_per_cycle
    train_success = [[] for _ in members]
    metrics: list[list[dict]] = [[] for _ in members]
    timing = {"collect": 0.0, "update": 0.0, "update_cpu": 0.0}

    def run_updates(n: int) -> None:
        t, cpu = time.perf_counter(), time.process_time()
        for _ in range(n):
            for i, row in enumerate(threads.timed(learner.update, replays, demo_buffers)):
                metrics[i].append(row)
        for m in members:
            m.state["updates"] += n
        timing["update"] += time.perf_counter() - t
        timing["update_cpu"] += time.process_time() - cpu

    owed = 0  # updates earned by the last collected cycle, not yet run
    for _ in range(s.cycles):
        t0 = time.perf_counter()
        update_before = timing["update"]
        seeds = [m.cfg.seed * TRAIN_SEED_STRIDE + m.state["episodes"] + j for m in members for j in range(per_member)]
        random_actions = members[0].state["env_steps"] < s.warmup_steps
        _start_collect(pool, learner, members, seeds, s.max_episode_steps, random_actions)
        while_first_rollout()
        if overlap:   # the workers play the cycle's episodes while the last cycle's updates run here
            run_updates(owed)
            owed = 0
        episodes = pool.rollout_wait()
        for i, m in enumerate(members):
            for j in range(per_member):
                e = i * per_member + j
                slot = m.replay.add_episode(episodes["observation"][0, e], episodes["achieved_goal"][0, e],
                                            episodes["desired_goal"][0, e, :-1], episodes["action"][0, e])
                learner.inputs[i].update(*m.replay.sample_episode_for_stats(slot))
                train_success[i].append(float(episodes["success"][0, e, -1]))
            m.state["episodes"] += per_member
            m.state["env_steps"] += per_member * s.max_episode_steps
        timing["collect"] += time.perf_counter() - t0 - (timing["update"] - update_before)
        earned = s.updates_per_cycle if members[0].state["env_steps"] >= s.warmup_steps else 0
        if overlap:
            owed = earned
        else:
            run_updates(earned)
    run_updates(owed)  # the last cycle's updates: the epoch's evaluation must see them

    out = []
    for i in range(len(members)):
        row = {"train_success_rate": float(np.mean(train_success[i])),
               "time_collect_s": round(timing["collect"], 3), "time_update_s": round(timing["update"], 3),
               # (of the epoch's time_cpu_learner_s: the updates' share, all the learner's threads)
               "time_cpu_learner_update_s": round(timing["update_cpu"], 3)}
        for key in (metrics[i][0] if metrics[i] else {}):
            row[key] = float(np.mean([r[key] for r in metrics[i] if key in r]))
        out.append(row)
    return out


def _start_collect(pool: EnvPool, learner: EnsembleDDPG, members: list[_Member], seeds: list[int], steps: int,
                   random_actions: bool) -> None:
    """Start one training episode in every env of the pool (member-major). Every member's exploration is drawn
    here from its own generator, in the order its single run draws it, so the workers draw nothing."""
    per_member = len(seeds) // len(members)
    member_of_env = np.repeat(np.arange(len(members)), per_member)
    if random_actions:   # warm-up: uniform actions from the member's collection generator, no policy
        random = np.concatenate([m.collect_rng.uniform(-1.0, 1.0, (steps, per_member, learner.act_dim)).astype(np.float32)
                                 for m in members], 1)
        explore = {"noise": None, "replace": np.ones(random.shape[:2], bool).T, "random": random.swapaxes(0, 1)}
        pool.rollout_async(seeds, None, member_of_env, explore)
        return
    parts = [learner.exploration(i, steps, per_member) for i in range(len(members))]
    explore = {k: (np.concatenate([p[k] for p in parts], 1).swapaxes(0, 1) if parts[0][k] is not None else None)
               for k in parts[0]}   # (T, E, ...) -> (E, T, ...)
    pool.rollout_async(seeds, learner.snapshot(), member_of_env, explore)


def _evaluate(pool: EnvPool, learner: EnsembleDDPG, episodes: int, steps: int,
              per_member: int) -> tuple[list[dict], list[list[dict]]]:
    """Every member's deterministic evaluation on the single run's seeds, through the pool (one message per
    worker for all rounds), scored by the proficiency metrics: the epoch's scores per member, and per member one
    row of metrics per episode (with grasp events where the env reports them)."""
    n_members = len(learner)
    rounds = -(-episodes // per_member)
    seeds = [[EVAL_SEED_BASE + r * per_member + j for _ in range(n_members) for j in range(per_member)]
             for r in range(rounds)]
    pool.rollout_async(seeds, learner.snapshot(), np.repeat(np.arange(n_members), per_member))
    out = pool.rollout_wait()
    trajectories = [[] for _ in range(n_members)]
    for r in range(rounds):
        for e in range(n_members * per_member):
            i, j = divmod(e, per_member)
            if r * per_member + j >= episodes:
                continue
            tip = out["tip_position"][r, e]
            flags = {"grasped": out["grasped"][r, e]} if "grasped" in out else {}
            trajectories[i].append(Trajectory(
                observation=out["observation"][r, e], achieved_goal=out["achieved_goal"][r, e],
                desired_goal=out["desired_goal"][r, e], action=out["action"][r, e], reward=out["reward"][r, e],
                success=out["success"][r, e], terminated=np.zeros(steps, bool),
                tip_position=tip.reshape(len(tip), -1, 3), jaw_angle=out["jaw_angle"][r, e].reshape(len(tip), -1),
                flags=flags))
    scores, episode_rows = [], []
    for trajs in trajectories:
        results = [trajectory_proficiency(t) for t in trajs]
        sm = summarize(results)
        scores.append({"success_rate": sm["final_success_rate"], "any_success_rate": sm["success_rate"],
                       "steps_to_complete": sm["mean_steps_to_success"], "economy_of_motion_cm": sm["mean_path_length_cm"]})
        rows = []
        for k, (t, p) in enumerate(zip(trajs, results)):
            rows.append({"episode": k, "seed": EVAL_SEED_BASE + k, **episode_row(t, p)})
        episode_rows.append(rows)
    return scores, episode_rows


# ---------------------------------------------------------------------- checkpoints, one per member
def _member_checkpoint(m: _Member, learner: EnsembleDDPG, i: int) -> dict:
    ckpt = {"format": CHECKPOINT_FORMAT, "config": json.dumps(_config_json(m.cfg)), "state": dict(m.state),
            "rows": json.dumps(m.log.rows), "learner": learner.member_state_dict(i), "replay": m.replay.state_dict(),
            "collect_rng": rng_state_tensor(m.collect_rng)}
    if m.demo_buffer is not None:
        ckpt["demo_buffer"] = m.demo_buffer.state_dict()
    return ckpt


def _checkpoints(members: list[_Member], learner: EnsembleDDPG) -> list[dict]:
    """Every member's checkpoint as of now (copies: training may go on before they are written)."""
    return [_member_checkpoint(m, learner, i) for i, m in enumerate(members)]


def _write_checkpoints(members: list[_Member], ckpts: list[dict]) -> None:
    tmps = []
    for m, ckpt in zip(members, ckpts):
        tmp = m.run_dir / "checkpoint.tmp"
        torch.save(ckpt, tmp)
        tmps.append(tmp)
    for m, tmp in zip(members, tmps):
        current = m.run_dir / "checkpoint.pt"
        if current.exists():
            os.replace(current, m.run_dir / PREV)
        os.replace(tmp, current)


def _load(path: Path) -> dict:
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a training checkpoint (format {ckpt.get('format')!r})")
    return ckpt


def _epoch_of(path: Path) -> int | None:
    return int(_load(path)["state"]["epoch"]) if path.is_file() else None


def _resume(members: list[_Member], learner: EnsembleDDPG) -> bool:
    """Load every member at the newest epoch that all of them have; False when there is nothing to resume."""
    if not members[0].cfg.resume:
        return False
    found = []
    for m in members:
        options = {}
        for name in ("checkpoint.pt", PREV):  # a .tmp may be half written: never read it
            path = m.run_dir / name
            epoch = _epoch_of(path)
            if epoch is not None:
                options.setdefault(epoch, path)
        found.append(options)
    if not any(found):
        return False
    common = set.intersection(*(set(o) for o in found))
    if not common:
        raise ValueError(f"the ensemble's run folders hold no common checkpoint epoch ({[sorted(o) for o in found]}); "
                         "were members added or removed? resume with the same sweep, or start new run folders")
    epoch = max(common)
    for i, (m, options) in enumerate(zip(members, found)):
        ckpt = _load(options[epoch])
        saved = json.loads(ckpt["config"])
        ignore = LAUNCH_SETTINGS
        if {k: v for k, v in saved.items() if k not in ignore} != \
                {k: v for k, v in _config_json(m.cfg).items() if k not in ignore}:
            raise ValueError(f"{options[epoch]} was written by a run with another configuration; resume with the "
                             f"same overrides, or start a new run folder. Saved: {saved}")
        learner.load_member_state_dict(i, ckpt["learner"])
        m.replay.load_state_dict(ckpt["replay"])
        if m.demo_buffer is not None:
            m.demo_buffer.load_state_dict(ckpt["demo_buffer"])
        m.collect_rng = rng_from_tensor(ckpt["collect_rng"])
        m.state, m.rows = dict(ckpt["state"]), json.loads(ckpt["rows"])
    print(f"resumed {len(members)} batched runs after epoch {epoch}")
    return True

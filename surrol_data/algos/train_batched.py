"""Several DDPG(+BC)+HER runs (seeds, demo sources) trained in one process as one batched ensemble.

The same run as :func:`surrol_data.algos.train.train`, for M runs at once, read top to bottom in
:func:`train_batched`:

1. one :class:`~surrol_data.algos.ensemble.EnsembleDDPG` holds the M members' networks stacked; every member
   keeps its own replay and demo buffers, normalisers, generators, run folder, ``metrics.jsonl`` and
   ``checkpoint.pt`` — the checkpoint is the single run's format, written from the member's slice;
2. offline phase: BC pre-training of all actors in one batched step each (and the optional critic warm-up);
3. online epochs: every cycle collects every member's ``episodes_per_cycle`` episodes at once in an
   :class:`~surrol_data.algos.env_pool.EnvPool` (M × episodes_per_cycle envs on ``n_workers`` processes),
   one batched actor call per env step for all members. With ``overlap`` the previous cycle's updates run
   in the parent *while the workers step the envs* (spread evenly over the episode's steps), so the two
   cores are busy with envs and updates at the same time; the cost is a policy one cycle staler than the
   serial schedule's (off-policy learning does not care) — ``overlap=False`` gives the serial schedule;
4. evaluation of all members through the same pool, deterministic, on the single run's evaluation seeds,
   scored by the same proficiency metrics; then per member one metrics row and one checkpoint.

A member's training episodes use the single run's seeds (``seed·1e6 + episode``) and the member draws its
batches and exploration noise from its own generator in the single run's order, so a member reproduces the
single run up to floating-point rounding of the batched kernels (and, with ``overlap``, the policy lag).

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
from surrol_data.algos.replay import EpisodeReplay, rng_from_tensor, rng_state_tensor
from surrol_data.algos.train import (CHECKPOINT_FORMAT, EVAL_SEED_BASE, TRAIN_SEED_STRIDE, RunLog, TrainConfig,
                                     _check, _config_json, _write_json, claim_run_dir, make_env)
from surrol_data.datasets.trajectory import TrajectoryBuilder
from surrol_data.evaluation.metrics import summarize, trajectory_proficiency

PREV = "checkpoint.prev.pt"


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
                  progress: bool = True) -> list[list[dict]]:
    """Train (or resume) the runs ``cfgs`` as one ensemble; returns every member's per-epoch rows."""
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
    members = []
    for cfg in cfgs:
        replay = EpisodeReplay(s.buffer_episodes, s.max_episode_steps, obs_dim, goal_dim, act_dim, reward_fn,
                               s.her_k, seed=cfg.seed)
        trajs, eps = load_demos(cfg.demos, cfg.env_id)
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
    pool = EnvPool(first.env_id, s.max_episode_steps, len(members) * per_member_envs, n_workers)
    demo_buffers = [m.demo_buffer for m in members] if members[0].demo_buffer is not None else None
    replays = [m.replay for m in members]

    def finish_epoch(extras: list[dict], started: float) -> None:
        t_eval = time.perf_counter()
        scores = _evaluate(pool, learner, s.eval_episodes, s.max_episode_steps, per_member_envs)
        eval_s = time.perf_counter() - t_eval
        elapsed = time.perf_counter() - started
        for i, m in enumerate(members):
            row = {"epoch": m.state["epoch"], "env_steps": m.state["env_steps"], "episodes": m.state["episodes"],
                   "updates": m.state["updates"], **scores[i], **extras[i]}
            row["time_eval_s"] = round(eval_s, 3)
            m.state["wall_s"] += elapsed  # the ensemble's epoch: every member waited for all of it
            row["wall_s"] = round(m.state["wall_s"], 3)
            m.log.append(row)
            learner.policy(i).save(m.run_dir / "policy.pt")
        _save_all(members, learner)

    bar = tqdm(total=s.epochs, initial=members[0].state["epoch"], unit="epoch", disable=not progress,
               desc=f"train {len(members)} runs {first.env_id.split('/')[-1]}")
    try:
        # 2. offline phase (epoch 0)
        if not members[0].rows:
            t0 = time.perf_counter()
            losses = [learner.pretrain_step(demo_buffers) for _ in range(s.offline_steps)] if demo_buffers else []
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
            extras = _online_epoch(members, learner, pool, replays, demo_buffers, overlap)
            finish_epoch(extras, t0)
            bar.update(1)
            bar.set_postfix(success=" ".join(f"{m.rows[-1]['success_rate']:.2f}" for m in members), refresh=False)
    finally:
        bar.close()
        pool.close()
        for m in members:
            if m.log is not None:
                m.log.close()
            _write_json(m.run_dir / "process.json", {**m.process, "finished": time.time(),
                                                     "epochs_done": m.state["epoch"]})
    return [m.log.rows for m in members]


def _online_epoch(members: list[_Member], learner: EnsembleDDPG, pool: EnvPool, replays, demo_buffers,
                  overlap: bool) -> list[dict]:
    s = members[0].cfg.schedule
    per_member = s.episodes_per_cycle
    train_success = [[] for _ in members]
    metrics: list[list[dict]] = [[] for _ in members]
    timing = {"collect": 0.0, "update": 0.0}

    def run_updates(n: int) -> None:
        t = time.perf_counter()
        for _ in range(n):
            for i, row in enumerate(learner.update(replays, demo_buffers)):
                metrics[i].append(row)
        for m in members:
            m.state["updates"] += n
        timing["update"] += time.perf_counter() - t

    owed = 0  # updates earned by the last collected cycle, not yet run
    for _ in range(s.cycles):
        t0 = time.perf_counter()
        update_before = timing["update"]
        seeds = [m.cfg.seed * TRAIN_SEED_STRIDE + m.state["episodes"] + j for m in members for j in range(per_member)]
        random_actions = members[0].state["env_steps"] < s.warmup_steps
        episodes = _collect(pool, learner, members, seeds, s.max_episode_steps, random_actions,
                            run_updates if overlap else None, owed if overlap else 0)
        if overlap:
            owed = 0
        for i, m in enumerate(members):
            for j in range(per_member):
                o, ag, g, a, success = (x[i * per_member + j] if x is not None else None for x in episodes)
                slot = m.replay.add_episode(o, ag, g, a)
                learner.inputs[i].update(*m.replay.sample_episode_for_stats(slot))
                train_success[i].append(float(success))
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
               "time_collect_s": round(timing["collect"], 3), "time_update_s": round(timing["update"], 3)}
        for key in (metrics[i][0] if metrics[i] else {}):
            row[key] = float(np.mean([r[key] for r in metrics[i] if key in r]))
        out.append(row)
    return out


def _collect(pool: EnvPool, learner: EnsembleDDPG, members: list[_Member], seeds: list[int], steps: int,
             random_actions: bool, run_updates, n_updates: int):
    """One episode in every env of the pool (member-major), running ``n_updates`` updates spread over the steps
    while the workers step. Returns per-env arrays: obs (E, T+1, ·), ag (E, T+1, ·), g (E, T, ·), actions
    (E, T, ·) and the last-step success (E,)."""
    per_member = len(seeds) // len(members)
    obs, _ = pool.reset(seeds)
    o, ag, g, acts = [obs["observation"]], [obs["achieved_goal"]], [], []
    info = {}
    done_updates = 0
    for t in range(steps):
        if random_actions:
            action = np.concatenate([m.collect_rng.uniform(-1.0, 1.0, (per_member, learner.act_dim)).astype(np.float32)
                                     for m in members])
        else:
            per = [{k: v[i * per_member:(i + 1) * per_member] for k, v in obs.items()} for i in range(len(members))]
            action = np.concatenate(learner.act(per, explore=True))
        g.append(obs["desired_goal"])
        pool.step_async(action)
        if run_updates is not None:
            due = (t + 1) * n_updates // steps - done_updates
            if due:
                run_updates(due)
                done_updates += due
        obs, _, info = pool.step_wait()
        o.append(obs["observation"])
        ag.append(obs["achieved_goal"])
        acts.append(action)
    swap = lambda xs: np.stack(xs, 1)  # (T, E, ·) -> (E, T, ·)
    return swap(o), swap(ag), swap(g), swap(acts), np.asarray(info["is_success"], float)


def _evaluate(pool: EnvPool, learner: EnsembleDDPG, episodes: int, steps: int, per_member: int) -> list[dict]:
    """Every member's deterministic evaluation on the single run's seeds, through the pool."""
    n_members = len(learner)
    trajectories = [[] for _ in range(n_members)]
    rounds = -(-episodes // per_member)
    for r in range(rounds):
        seeds = [EVAL_SEED_BASE + r * per_member + j for _ in range(n_members) for j in range(per_member)]
        obs, info = pool.reset(seeds)
        builders = [TrajectoryBuilder({k: v[e] for k, v in obs.items()}, info["tip_position"][e], info["jaw_angle"][e])
                    for e in range(len(seeds))]
        for _ in range(steps):
            per = [{k: v[i * per_member:(i + 1) * per_member] for k, v in obs.items()} for i in range(n_members)]
            action = np.clip(np.concatenate(learner.act(per, explore=False)), -1.0, 1.0)
            obs, reward, info = pool.step(action)
            for e, b in enumerate(builders):
                b.add(action[e], {k: v[e] for k, v in obs.items()}, reward[e], bool(info["is_success"][e]), False,
                      info["tip_position"][e], info["jaw_angle"][e])
        for e, b in enumerate(builders):
            i, j = divmod(e, per_member)
            if r * per_member + j < episodes:
                trajectories[i].append(b.build())
    out = []
    for trajs in trajectories:
        sm = summarize([trajectory_proficiency(t) for t in trajs])
        out.append({"success_rate": sm["final_success_rate"], "any_success_rate": sm["success_rate"],
                    "steps_to_complete": sm["mean_steps_to_success"], "economy_of_motion_cm": sm["mean_path_length_cm"]})
    return out


# ---------------------------------------------------------------------- checkpoints, one per member
def _member_checkpoint(m: _Member, learner: EnsembleDDPG, i: int) -> dict:
    ckpt = {"format": CHECKPOINT_FORMAT, "config": json.dumps(_config_json(m.cfg)), "state": dict(m.state),
            "rows": json.dumps(m.log.rows), "learner": learner.member_state_dict(i), "replay": m.replay.state_dict(),
            "collect_rng": rng_state_tensor(m.collect_rng)}
    if m.demo_buffer is not None:
        ckpt["demo_buffer"] = m.demo_buffer.state_dict()
    return ckpt


def _save_all(members: list[_Member], learner: EnsembleDDPG) -> None:
    tmps = []
    for i, m in enumerate(members):
        tmp = m.run_dir / "checkpoint.tmp"
        torch.save(_member_checkpoint(m, learner, i), tmp)
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
        ignore = ("resume", "progress")
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

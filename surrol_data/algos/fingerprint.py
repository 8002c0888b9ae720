"""Fingerprint of the batched DDPG(+BC)+HER learner: what it computes on fixed data, hashed.

A study whose runs train over days is only one study while the learner computes the same thing. The fingerprint
runs the learner exactly as :func:`~surrol_data.algos.train_batched.train_batched` drives it — two members, HER
replay and demo buffers filled with fixed synthetic episodes, normaliser updates, BC pre-training steps, online
updates, the exploration draws and the workers' policy snapshot acting on fixed observations — and hashes every
weight, loss and action it produced. Any change to what the learner computes changes it; a pure refactor keeps
it bit for bit **on one machine** (floating-point bits differ between CPUs).
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch

from surrol_data.algos.ddpg import DDPGConfig
from surrol_data.algos.ensemble import EnsembleDDPG
from surrol_data.algos.env_pool import SnapshotActor
from surrol_data.algos.replay import EpisodeReplay
from surrol_data.envs.fingerprint import feed

EPISODES, HORIZON = 8, 40
PRETRAIN_STEPS, UPDATES = 10, 10


def _episode(rng: np.random.Generator, obs_dim: int, goal_dim: int, act_dim: int):
    obs = rng.normal(0.0, 0.05, (HORIZON + 1, obs_dim)).astype(np.float32)
    ag = (rng.normal(0.0, 0.02, goal_dim) + np.cumsum(rng.normal(0.0, 0.002, (HORIZON + 1, goal_dim)), 0)).astype(np.float32)
    g = np.repeat(rng.normal(0.0, 0.02, (1, goal_dim)), HORIZON, 0).astype(np.float32)
    action = rng.uniform(-1.0, 1.0, (HORIZON, act_dim)).astype(np.float32)
    return obs, ag, g, action


def learner_fingerprint(config: DDPGConfig, obs_dim: int, goal_dim: int, act_dim: int, reward_fn, her_k: int,
                        seeds: tuple[int, ...] = (0, 1)) -> str:
    """Hex digest of what :class:`EnsembleDDPG` computes from fixed data with ``config`` (the run's learner
    parameters); ``reward_fn`` is the task's ``compute_reward`` (HER relabels through it)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)   # the study's learners run single-threaded; thread count may change reductions
    try:
        learner = EnsembleDDPG(obs_dim, goal_dim, act_dim, config, list(seeds))
        data = np.random.default_rng(12345)
        replays, demos = [], []
        for i, seed in enumerate(seeds):
            replay = EpisodeReplay(2 * EPISODES, HORIZON, obs_dim, goal_dim, act_dim, reward_fn, her_k, seed=seed)
            demo = EpisodeReplay(EPISODES, HORIZON, obs_dim, goal_dim, act_dim, reward_fn, her_k, seed=seed + 1)
            for _ in range(EPISODES):
                episode = _episode(data, obs_dim, goal_dim, act_dim)
                slot = demo.add_episode(*episode)
                learner.inputs[i].update(*demo.sample_episode_for_stats(slot))
                replay.add_episode(*episode)
                slot = replay.add_episode(*_episode(data, obs_dim, goal_dim, act_dim))
                learner.inputs[i].update(*replay.sample_episode_for_stats(slot))
            replays.append(replay)
            demos.append(demo)
        h = hashlib.sha256()
        feed(h, [learner.pretrain_step(demos) for _ in range(PRETRAIN_STEPS)])
        learner.finish_pretraining()
        feed(h, [learner.pretrain_critic_step(demos) for _ in range(config.critic_pretrain_steps and 2)])
        feed(h, [learner.update(replays, demos) for _ in range(UPDATES)])
        for net in (learner.actor, learner.critic, learner.actor_target, learner.critic_target):
            feed(h, [p.detach().numpy() for p in net.parameters()])
        feed(h, learner.exploration(0, 3, 2))
        obs = data.normal(0.0, 0.05, (len(seeds), obs_dim)).astype(np.float32)
        goal = data.normal(0.0, 0.02, (len(seeds), goal_dim)).astype(np.float32)
        feed(h, SnapshotActor(learner.snapshot())(obs, goal))
        return h.hexdigest()
    finally:
        torch.set_num_threads(threads)

"""Behaviour cloning: regress the demonstrator's action from (observation, desired goal).

Reads top to bottom:

1. split the demo samples into train / hold-out (whole episodes when episode ids are given, so
   near-duplicate neighbouring steps of one episode do not leak into the hold-out set);
2. fit the observation and goal normalisers on the training split;
3. train a :class:`~surrol_data.algos.networks.DeterministicActor` on normalised ``[o, g]`` with MSE to
   the demo action and Adam, minibatches drawn uniformly with replacement (as DEX's buffers do) — or, with
   ``gmm_modes`` > 0, a :class:`~surrol_data.algos.networks.GMMActor` by the demo action's negative
   log-likelihood (robomimic's BC-GMM, the choice for people's demos, whose pauses a mean cannot represent);
4. after every epoch (a fixed number of gradient steps, robomimic's convention, so the cost does not
   depend on the dataset size) record the train loss and the hold-out loss in ``policy.log`` (MSE, or the
   negative log-likelihood per sample for BC-GMM).

Defaults are SurRoL-v2's BC (lr 1e-3, batch 128, 3×256 MLP; reference §2 "BC"), which is also
robomimic's choice for machine-generated low-dimensional data (§6.1).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from surrol_data.algos.networks import DEFAULT_HIDDEN_SIZES, DeterministicActor, GMMActor
from surrol_data.algos.normalizer import Normalizer

CHECKPOINT_FORMAT = "surrol_data.bc/1"


@dataclass
class BCConfig:
    hidden_sizes: tuple[int, ...] = DEFAULT_HIDDEN_SIZES
    lr: float = 1e-3
    batch_size: int = 128
    epochs: int = 20
    steps_per_epoch: int = 100      # gradient steps per epoch; total = epochs × steps_per_epoch
    val_fraction: float = 0.1       # share of episodes (or samples, without episode ids) held out
    norm_eps: float = 0.01
    norm_clip: float = 5.0
    seed: int = 0
    # One thread: results that do not depend on the core count (reductions split across threads round
    # differently), ~3 s for 2000 steps on a 2-core CPU, and no slowdown when other jobs share the cores.
    num_threads: int = 1
    # 0: a deterministic actor fit by MSE. N > 0: robomimic's BC-GMM with N modes (robomimic uses 5), acting by
    # drawing a mode from a generator seeded with ``seed`` (the same rollouts for the same seed and episode order).
    gmm_modes: int = 0
    gmm_min_std: float = 0.01


def demo_arrays(trajectories: Sequence) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flatten trajectories into BC samples ``(obs, goal, action, episode_index)``.

    Sample t pairs the observation and desired goal *before* action t with action t; the final
    observation of each trajectory has no action and is dropped.
    """
    if not trajectories:
        raise ValueError("demo_arrays needs at least one trajectory")
    obs = np.concatenate([t.observation[:-1] for t in trajectories]).astype(np.float32)
    goal = np.concatenate([t.desired_goal[:-1] for t in trajectories]).astype(np.float32)
    action = np.concatenate([t.action for t in trajectories]).astype(np.float32)
    episode = np.concatenate([np.full(len(t), i, np.int64) for i, t in enumerate(trajectories)])
    return obs, goal, action, episode


class BCPolicy:
    """A trained BC actor with its normalisers: numpy obs dict in, numpy action out."""

    def __init__(self, actor: DeterministicActor | GMMActor, obs_norm: Normalizer, goal_norm: Normalizer,
                 config: BCConfig, log: list[dict] | None = None):
        self.actor = actor.eval()
        self.obs_norm = obs_norm
        self.goal_norm = goal_norm
        self.config = config
        self.log = log if log is not None else []
        # BC-GMM draws a mode per action: from its own generator, so rollouts repeat for a seed and never
        # depend on (or disturb) the caller's global torch seed.
        self.generator = torch.Generator().manual_seed(config.seed) if isinstance(actor, GMMActor) else None

    def act(self, obs: dict) -> np.ndarray:
        """Action for one obs dict (arrays of shape (dim,)) or a batch (arrays of shape (B, dim))."""
        o = np.asarray(obs["observation"], np.float32)
        g = np.asarray(obs["desired_goal"], np.float32)
        if o.shape[-1:] != (self.actor.obs_dim,) or g.shape[-1:] != (self.actor.goal_dim,):
            raise ValueError(
                f"policy was trained on observation dim {self.actor.obs_dim} and goal dim {self.actor.goal_dim}, "
                f"got shapes {o.shape} and {g.shape}; is it evaluated on the task it was trained on?")
        o_t, g_t = torch.from_numpy(self.obs_norm.normalize(o)), torch.from_numpy(self.goal_norm.normalize(g))
        with torch.inference_mode():
            a = self.actor(o_t, g_t) if self.generator is None else self.actor(o_t, g_t, generator=self.generator)
        return a.numpy().astype(np.float32)

    __call__ = act

    @property
    def torch_threads(self) -> int:
        """Threads to roll it out with (:func:`surrol_data.evaluation.rollout.evaluate` sets them): the training
        count, 1 by default. Its matmuls are tiny, so more threads only add synchronisation (8-15x slower on a
        2-core machine at torch's default of one thread per core), and one thread gives the same actions
        whatever the core count."""
        return self.config.num_threads

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        config = asdict(self.config)
        config["hidden_sizes"] = list(config["hidden_sizes"])
        torch.save({
            "format": CHECKPOINT_FORMAT,
            "config": config,
            "dims": {"obs": self.actor.obs_dim, "goal": self.actor.goal_dim, "act": self.actor.act_dim},
            "obs_norm": self.obs_norm.state_dict(),
            "goal_norm": self.goal_norm.state_dict(),
            "actor": self.actor.state_dict(),
            "log": self.log,
        }, path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> BCPolicy:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no BC checkpoint at {path}")
        # weights_only: a checkpoint is data, never code to run.
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
            found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
            raise ValueError(f"{path} is not a BC checkpoint (format {found!r}, expected {CHECKPOINT_FORMAT!r})")
        config = BCConfig(**{**ckpt["config"], "hidden_sizes": tuple(ckpt["config"]["hidden_sizes"])})
        dims = ckpt["dims"]
        actor = _actor(dims["obs"], dims["goal"], dims["act"], config)
        actor.load_state_dict(ckpt["actor"])
        return cls(actor, Normalizer.from_state_dict(ckpt["obs_norm"]), Normalizer.from_state_dict(ckpt["goal_norm"]),
                   config, ckpt["log"])


def train_bc(obs: np.ndarray, goal: np.ndarray, action: np.ndarray, config: BCConfig,
             episode_index: np.ndarray | None = None, progress: bool = True) -> BCPolicy:
    """Train a BC policy on samples ``obs`` (N, obs_dim), ``goal`` (N, goal_dim), ``action`` (N, act_dim).

    ``episode_index`` (N,) optional: hold out whole episodes instead of single samples.
    Deterministic for a given ``config.seed`` (and thread count). The per-epoch losses are in ``policy.log``.
    """
    obs, goal, action = (np.asarray(x, np.float32) for x in (obs, goal, action))
    n = len(obs)
    if obs.ndim != 2 or goal.ndim != 2 or action.ndim != 2 or not (len(goal) == len(action) == n):
        raise ValueError(f"train_bc expects 2-D arrays with the same number of rows, got obs {obs.shape}, "
                         f"goal {goal.shape}, action {action.shape}")
    if n == 0:
        raise ValueError("train_bc got no samples")
    if min(config.epochs, config.steps_per_epoch, config.batch_size, config.num_threads) < 1 or config.gmm_modes < 0:
        raise ValueError(f"epochs, steps_per_epoch, batch_size and num_threads must be >= 1 and gmm_modes >= 0, "
                         f"got {config}")
    if np.abs(action).max() > 1.0 + 1e-6:
        raise ValueError(f"demo actions must lie in [-1, 1] (the actor is tanh-bounded), max |a| = {np.abs(action).max():.3f}")

    # 1. Hold-out split.
    rng = np.random.default_rng(config.seed)
    train_rows, val_rows = _split(n, episode_index, config.val_fraction, rng)

    # 2. Normalisers see the training split only, so the hold-out loss measures generalisation honestly.
    obs_norm = Normalizer(obs.shape[1], config.norm_eps, config.norm_clip)
    goal_norm = Normalizer(goal.shape[1], config.norm_eps, config.norm_clip)
    obs_norm.update(obs[train_rows])
    goal_norm.update(goal[train_rows])
    o_all = torch.from_numpy(obs_norm.normalize(obs))
    g_all = torch.from_numpy(goal_norm.normalize(goal))
    a_all = torch.from_numpy(action)
    train_t = torch.from_numpy(train_rows)
    val_t = torch.from_numpy(val_rows)

    # 3. Actor and optimiser. The initial weights come from a forked RNG so training neither depends on
    # nor disturbs the caller's global torch seed.
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        actor = _actor(obs.shape[1], goal.shape[1], action.shape[1], config)
    optimizer = torch.optim.Adam(actor.parameters(), lr=config.lr)
    batch_gen = torch.Generator().manual_seed(config.seed)

    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.num_threads)
    log: list[dict] = []
    total_steps = config.epochs * config.steps_per_epoch
    bar = tqdm(total=total_steps, desc="BC", disable=not progress, leave=False)
    try:
        step = 0
        for epoch in range(1, config.epochs + 1):
            actor.train()
            epoch_loss = 0.0
            for _ in range(config.steps_per_epoch):
                rows = train_t[torch.randint(len(train_t), (config.batch_size,), generator=batch_gen)]
                loss = _loss(actor, o_all[rows], g_all[rows], a_all[rows])
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                epoch_loss += loss.item()
                step += 1
                bar.update(1)

            # 4. Per-epoch record: mean train loss over the epoch's steps, full hold-out loss.
            val_loss = float("nan")
            if len(val_t):
                actor.eval()
                with torch.inference_mode():
                    val_loss = _loss(actor, o_all[val_t], g_all[val_t], a_all[val_t]).item()
            log.append({"epoch": epoch, "step": step,
                        "train_loss": epoch_loss / config.steps_per_epoch, "val_loss": val_loss})
            bar.set_postfix(loss=f"{log[-1]['train_loss']:.2e}", val=f"{val_loss:.2e}")
    finally:
        bar.close()
        torch.set_num_threads(previous_threads)

    return BCPolicy(actor, obs_norm, goal_norm, config, log)


def _actor(obs_dim: int, goal_dim: int, act_dim: int, config: BCConfig) -> DeterministicActor | GMMActor:
    if config.gmm_modes:
        return GMMActor(obs_dim, goal_dim, act_dim, config.gmm_modes, config.hidden_sizes, config.gmm_min_std)
    return DeterministicActor(obs_dim, goal_dim, act_dim, config.hidden_sizes)


def _loss(actor: DeterministicActor | GMMActor, obs: torch.Tensor, goal: torch.Tensor,
          action: torch.Tensor) -> torch.Tensor:
    if isinstance(actor, GMMActor):
        return -actor.log_prob(obs, goal, action).mean()
    return F.mse_loss(actor(obs, goal), action)


def _split(n: int, episode_index: np.ndarray | None, val_fraction: float,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Row indices of the train and hold-out sets; the hold-out set is empty when there is too little data."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    if episode_index is None:
        groups = np.arange(n)
    else:
        groups = np.asarray(episode_index)
        if groups.shape != (n,):
            raise ValueError(f"episode_index must have shape ({n},), got {groups.shape}")
    units = np.unique(groups)
    n_val = int(round(val_fraction * len(units)))
    if val_fraction > 0 and len(units) >= 2:
        n_val = min(max(n_val, 1), len(units) - 1)  # keep at least one unit on each side
    else:
        n_val = 0
    val_units = rng.permutation(units)[:n_val]
    is_val = np.isin(groups, val_units)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)

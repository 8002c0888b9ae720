"""Episode replay buffer with hindsight relabelling ("future" strategy), for agent and demo episodes alike.

Storage is episode-major, as in baselines/DEX (reference §1.3): ``obs`` and ``ag`` hold T+1 rows per
episode, ``g`` and ``action`` T rows. Episodes may be shorter than the buffer's horizon T (human demos,
truncated runs): each slot remembers its length and sampling never reads past it.

Sampling one transition: an episode uniformly, a step t uniformly in [0, len−1]; with probability
``her_ratio`` (0.8 for k = 4, since 1 − 1/(1+k) = 0.8) the goal is replaced by the achieved goal of a
uniformly chosen later state t+1 … len, and the reward is recomputed for the whole batch with the env's
vectorised ``compute_reward(ag_next, g)``. ``done`` is not returned on purpose: SurRoL episodes end by time
limit only, so the learners bootstrap every transition (reference §7.1).

Once full, new episodes overwrite *random* slots (DEX's rule), drawn from the buffer's own generator so a
resumed run overwrites the same slots as an uninterrupted one.
"""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np
import torch

RewardFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def her_ratio_for(k: int) -> float:
    """Share of relabelled samples for ``k`` hindsight goals per real one: 1 − 1/(1+k)."""
    if k < 0:
        raise ValueError(f"HER k must be >= 0, got {k}")
    return 1.0 - 1.0 / (1.0 + k)


class EpisodeReplay:
    def __init__(self, capacity_episodes: int, horizon: int, obs_dim: int, goal_dim: int, act_dim: int,
                 reward_fn: RewardFn, her_k: int = 4, seed: int = 0):
        if capacity_episodes < 1 or horizon < 1:
            raise ValueError(f"capacity_episodes and horizon must be >= 1, got {capacity_episodes}, {horizon}")
        self.capacity, self.horizon = int(capacity_episodes), int(horizon)
        self.obs_dim, self.goal_dim, self.act_dim = int(obs_dim), int(goal_dim), int(act_dim)
        self.reward_fn = reward_fn
        self.her_ratio = her_ratio_for(her_k)
        n, t = self.capacity, self.horizon
        self.obs = np.zeros((n, t + 1, obs_dim), np.float32)
        self.ag = np.zeros((n, t + 1, goal_dim), np.float32)
        self.g = np.zeros((n, t, goal_dim), np.float32)
        self.action = np.zeros((n, t, act_dim), np.float32)
        self.length = np.zeros(n, np.int64)
        self.size = 0
        self.episodes_added = 0
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return self.size

    @property
    def transitions(self) -> int:
        return int(self.length[: self.size].sum())

    def add_episode(self, obs: np.ndarray, ag: np.ndarray, g: np.ndarray, action: np.ndarray) -> int:
        """Store one episode: ``obs``/``ag`` (L+1, dim), ``g``/``action`` (L, dim) with 1 <= L; steps past the
        buffer's horizon are dropped. Returns the slot used."""
        n_act = len(action)
        if n_act < 1 or len(obs) != n_act + 1 or len(ag) != n_act + 1 or len(g) != n_act:
            raise ValueError(f"an episode needs L >= 1 actions, L goals and L+1 observations/achieved goals; got "
                             f"obs {len(obs)}, ag {len(ag)}, g {len(g)}, action {n_act}")
        if (np.shape(obs)[-1], np.shape(ag)[-1], np.shape(action)[-1]) != (self.obs_dim, self.goal_dim, self.act_dim):
            raise ValueError(f"episode dims (obs {np.shape(obs)[-1]}, goal {np.shape(ag)[-1]}, action "
                             f"{np.shape(action)[-1]}) do not match the buffer's ({self.obs_dim}, {self.goal_dim}, "
                             f"{self.act_dim}); are the demos from the same task as the env?")
        n = min(n_act, self.horizon)
        if self.size < self.capacity:
            slot = self.size
            self.size += 1
        else:
            slot = int(self.rng.integers(self.capacity))
        self.obs[slot, : n + 1] = obs[: n + 1]
        self.ag[slot, : n + 1] = ag[: n + 1]
        self.g[slot, :n] = g[:n]
        self.action[slot, :n] = action[:n]
        self.length[slot] = n
        self.episodes_added += 1
        return slot

    def sample(self, batch_size: int, rng: np.random.Generator | None = None) -> dict[str, np.ndarray]:
        """A HER-relabelled batch: obs, next_obs, g, action, reward (and ag, next_ag) as float32 arrays."""
        if self.size == 0:
            raise RuntimeError("cannot sample from an empty replay buffer")
        rng = self.rng if rng is None else rng
        ep = rng.integers(self.size, size=batch_size)
        length = self.length[ep]
        t = (rng.random(batch_size) * length).astype(np.int64)
        g = self.g[ep, t].copy()
        relabel = rng.random(batch_size) < self.her_ratio
        # future index uniform in t+1 … length (inclusive): the achieved goal after this or a later action
        future = t + 1 + (rng.random(batch_size) * (length - t)).astype(np.int64)
        g[relabel] = self.ag[ep[relabel], future[relabel]]
        next_ag = self.ag[ep, t + 1]
        return {
            "obs": self.obs[ep, t], "next_obs": self.obs[ep, t + 1], "ag": self.ag[ep, t], "next_ag": next_ag,
            "g": g, "action": self.action[ep, t],
            "reward": np.asarray(self.reward_fn(next_ag, g), np.float32).reshape(batch_size),
        }

    def sample_episode_for_stats(self, slot: int, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(obs, relabelled goal) for ``len`` random transitions of one stored episode: what the normalisers see
        (DEX updates its statistics with HER-relabelled goals, reference §1.2)."""
        rng = self.rng if rng is None else rng
        n = int(self.length[slot])
        t = rng.integers(n, size=n)
        g = self.g[slot, t].copy()
        relabel = rng.random(n) < self.her_ratio
        future = t + 1 + (rng.random(n) * (n - t)).astype(np.int64)
        g[relabel] = self.ag[slot, future[relabel]]
        return self.obs[slot, t], g

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict:
        """Only the filled slots, as tensors (so ``torch.load(weights_only=True)`` accepts it)."""
        s = self.size
        return {"size": s, "episodes_added": self.episodes_added, "rng": rng_state_tensor(self.rng),
                "obs": torch.from_numpy(self.obs[:s].copy()), "ag": torch.from_numpy(self.ag[:s].copy()),
                "g": torch.from_numpy(self.g[:s].copy()), "action": torch.from_numpy(self.action[:s].copy()),
                "length": torch.from_numpy(self.length[:s].copy())}

    def load_state_dict(self, state: dict) -> None:
        s = int(state["size"])
        if s > self.capacity or tuple(state["obs"].shape[1:]) != self.obs.shape[1:]:
            raise ValueError(f"checkpointed buffer (size {s}, obs {tuple(state['obs'].shape)}) does not fit this "
                             f"buffer (capacity {self.capacity}, obs {self.obs.shape}); was the config changed?")
        self.size, self.episodes_added = s, int(state["episodes_added"])
        for name in ("obs", "ag", "g", "action", "length"):
            getattr(self, name)[:s] = state[name].numpy()
        self.rng = rng_from_tensor(state["rng"])


def rng_state_tensor(rng: np.random.Generator) -> torch.Tensor:
    """A numpy Generator's exact state as a uint8 tensor (checkpoints hold tensors and plain scalars only)."""
    return torch.frombuffer(bytearray(json.dumps(rng.bit_generator.state).encode()), dtype=torch.uint8).clone()


def rng_from_tensor(blob: torch.Tensor) -> np.random.Generator:
    state = json.loads(bytes(blob.numpy().tobytes()).decode())
    rng = np.random.Generator(getattr(np.random, state["bit_generator"])())
    rng.bit_generator.state = state
    return rng

"""What a goal-conditioned network sees: clipped, running-normalised observation and desired goal.

One pair of :class:`~surrol_data.algos.normalizer.Normalizer` shared by actor and critic (DEX §1.2): raw
values are clipped to ±``clip_obs`` before their statistics are taken and before they are normalised on
the training path. The acting path skips that clip, as DEX does; with real-metre observations it never binds.
"""

from __future__ import annotations

import numpy as np
import torch

from surrol_data.algos.normalizer import Normalizer


class GoalInputs:
    def __init__(self, obs_dim: int, goal_dim: int, clip_obs: float = 200.0, eps: float = 0.01, clip: float = 5.0):
        self.clip_obs = float(clip_obs)
        self.obs_norm = Normalizer(obs_dim, eps, clip)
        self.goal_norm = Normalizer(goal_dim, eps, clip)
        self.frozen = False  # True: update() keeps the statistics as they are (ddpgbc_warm's demo statistics)

    def update(self, obs: np.ndarray, goal: np.ndarray) -> None:
        if self.frozen:
            return
        self.obs_norm.update(np.clip(obs, -self.clip_obs, self.clip_obs))
        self.goal_norm.update(np.clip(goal, -self.clip_obs, self.clip_obs))

    def __call__(self, obs: np.ndarray, goal: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised (obs, goal) tensors for the training path."""
        o = self.obs_norm.normalize(np.clip(obs, -self.clip_obs, self.clip_obs))
        g = self.goal_norm.normalize(np.clip(goal, -self.clip_obs, self.clip_obs))
        return torch.from_numpy(o), torch.from_numpy(g)

    def state_dict(self) -> dict:
        return {"clip_obs": self.clip_obs, "obs": self.obs_norm.state_dict(), "goal": self.goal_norm.state_dict(),
                "frozen": self.frozen}

    def load_state_dict(self, state: dict) -> None:
        self.clip_obs = float(state["clip_obs"])
        self.obs_norm.load_state_dict(state["obs"])
        self.goal_norm.load_state_dict(state["goal"])
        self.frozen = bool(state.get("frozen", False))

"""Network building blocks shared by the learners (BC now; DDPG and SAC reuse them).

Defaults follow DEX (reference §1.1): 3 hidden layers × 256 units, ReLU, PyTorch default init.
Networks take already-normalised inputs: normalisation is data statistics, kept outside the module
(see :mod:`surrol_data.algos.normalizer`) so a learner can update it without touching weights.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

DEFAULT_HIDDEN_SIZES = (256, 256, 256)


def mlp(in_dim: int, out_dim: int, hidden_sizes: Sequence[int] = DEFAULT_HIDDEN_SIZES,
        activation: type[nn.Module] = nn.ReLU) -> nn.Sequential:
    """Linear–act–…–Linear with a linear output (the caller adds any squashing)."""
    if in_dim <= 0 or out_dim <= 0:
        raise ValueError(f"mlp needs positive input and output sizes, got in_dim={in_dim}, out_dim={out_dim}")
    layers: list[nn.Module] = []
    last = in_dim
    for width in hidden_sizes:
        layers += [nn.Linear(last, int(width)), activation()]
        last = int(width)
    layers.append(nn.Linear(last, out_dim))
    return nn.Sequential(*layers)


class DeterministicActor(nn.Module):
    """π(o, g) = max_action · tanh(MLP([o, g])): a deterministic goal-conditioned policy with bounded output."""

    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int,
                 hidden_sizes: Sequence[int] = DEFAULT_HIDDEN_SIZES, max_action: float = 1.0):
        super().__init__()
        self.obs_dim, self.goal_dim, self.act_dim = int(obs_dim), int(goal_dim), int(act_dim)
        self.max_action = float(max_action)
        self.net = mlp(self.obs_dim + self.goal_dim, self.act_dim, hidden_sizes)

    def forward(self, obs: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return self.max_action * torch.tanh(self.net(torch.cat([obs, goal], dim=-1)))

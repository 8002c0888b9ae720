"""Network building blocks shared by the learners (BC, DDPG, SAC).

Defaults follow DEX (reference §1.1): 3 hidden layers × 256 units, ReLU, PyTorch default init.
Networks take already-normalised inputs: normalisation is data statistics, kept outside the module
(see :mod:`surrol_data.algos.normalizer`) so a learner can update it without touching weights.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
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


class Critic(nn.Module):
    """Q(o, g, a) = MLP([o, g, a]): normalised observation and goal, raw action in [-1, 1] (DEX §1.1)."""

    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int,
                 hidden_sizes: Sequence[int] = DEFAULT_HIDDEN_SIZES):
        super().__init__()
        self.obs_dim, self.goal_dim, self.act_dim = int(obs_dim), int(goal_dim), int(act_dim)
        self.net = mlp(self.obs_dim + self.goal_dim + self.act_dim, 1, hidden_sizes)

    def forward(self, obs: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, goal, action], dim=-1)).squeeze(-1)


class SquashedGaussianActor(nn.Module):
    """SAC's policy: a = tanh(μ + σ·ε) with the exact log-probability of the squashed sample.

    log σ is squashed into [log_std_min, log_std_max] with a tanh (DEX's [−4, 2]) rather than hard-clipped,
    so its gradient never vanishes at the bounds.
    """

    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int,
                 hidden_sizes: Sequence[int] = DEFAULT_HIDDEN_SIZES, log_std_min: float = -4.0, log_std_max: float = 2.0):
        super().__init__()
        self.obs_dim, self.goal_dim, self.act_dim = int(obs_dim), int(goal_dim), int(act_dim)
        self.log_std_min, self.log_std_max = float(log_std_min), float(log_std_max)
        self.net = mlp(self.obs_dim + self.goal_dim, 2 * self.act_dim, hidden_sizes)

    def forward(self, obs: torch.Tensor, goal: torch.Tensor, deterministic: bool = False,
                generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(action, log π(action)); deterministic gives tanh(μ) and a log-probability of zeros."""
        mu, raw_log_std = self.net(torch.cat([obs, goal], dim=-1)).chunk(2, dim=-1)
        if deterministic:
            return torch.tanh(mu), torch.zeros(mu.shape[:-1])
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (torch.tanh(raw_log_std) + 1.0)
        std = log_std.exp()
        eps = torch.randn(mu.shape, generator=generator)
        pre_tanh = mu + std * eps
        action = torch.tanh(pre_tanh)
        # log N(pre_tanh; μ, σ) − Σ log(1 − tanh²), the latter in the numerically stable softplus form.
        log_prob = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        log_prob = log_prob - (2.0 * (math.log(2.0) - pre_tanh - F.softplus(-2.0 * pre_tanh))).sum(-1)
        return action, log_prob


class GMMActor(nn.Module):
    """robomimic's BC-GMM policy head: π(a | o, g) a mixture of ``modes`` diagonal Gaussians, means tanh-bounded.

    People hesitate: at the grasp pose an operator holds the jaw open for a while, then closes it from nearly the
    same state. A deterministic actor fit by MSE predicts the average of "hold" and "close" there and never closes;
    a mixture keeps both as modes with their weights, so a rollout that picks a mode by its weight closes after
    about as long as the person did. Acting uses robomimic's low-noise evaluation: draw a mode by its weight and
    act its mean (the per-mode spread is the operators' tremor, not something to replay).
    """

    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int, modes: int = 5,
                 hidden_sizes: Sequence[int] = DEFAULT_HIDDEN_SIZES, min_std: float = 0.01):
        super().__init__()
        if modes < 1:
            raise ValueError(f"GMMActor needs at least one mode, got {modes}")
        self.obs_dim, self.goal_dim, self.act_dim = int(obs_dim), int(goal_dim), int(act_dim)
        self.modes, self.min_std = int(modes), float(min_std)
        self.net = mlp(self.obs_dim + self.goal_dim, self.modes * (2 * self.act_dim + 1), hidden_sizes)

    def _heads(self, obs: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self.net(torch.cat([obs, goal], dim=-1))
        split = self.modes * self.act_dim
        shape = (*out.shape[:-1], self.modes, self.act_dim)
        means = torch.tanh(out[..., :split]).reshape(shape)
        std = F.softplus(out[..., split:2 * split]).reshape(shape) + self.min_std
        return means, std, out[..., 2 * split:]

    def log_prob(self, obs: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """log π(action | o, g), one value per row."""
        means, std, logits = self._heads(obs, goal)
        per_mode = torch.distributions.Normal(means, std).log_prob(action.unsqueeze(-2)).sum(-1)
        return torch.logsumexp(per_mode + torch.log_softmax(logits, dim=-1), dim=-1)

    def forward(self, obs: torch.Tensor, goal: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """The mean of a mode drawn by its weight (low-noise evaluation); rows are drawn independently."""
        means, _, logits = self._heads(obs, goal)
        flat_logits = logits.reshape(-1, self.modes)
        mode = torch.multinomial(torch.softmax(flat_logits, dim=-1), 1, generator=generator).squeeze(-1)
        chosen = means.reshape(-1, self.modes, self.act_dim)[torch.arange(len(mode)), mode]
        return chosen.reshape(*means.shape[:-2], self.act_dim)


def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging θ' ← τθ + (1 − τ)θ' in place."""
    with torch.no_grad():
        # one fused call over all tensors: a per-parameter Python loop costs 4x more on these small nets
        torch._foreach_lerp_(list(target.parameters()), list(source.parameters()), tau)

"""Soft actor-critic on goal-conditioned inputs, with or without hindsight relabelling (DEX's ``sac``, reference §2).

Per :meth:`SAC.update` iteration, on one batch from the replay buffer (which also holds the demos, if any;
HER or not is the buffer's ``her_k``):

1. critics ← MSE(Q_i(s, a), y), y = r + γ·(min_i Q'_i(s', a') − α·log π(a'|s')), a' ~ π(·|s');
   optionally clamped to [−1/(1−γ), 0] (off in DEX; the sparse return can never leave that range);
2. actor ← mean(α·log π(a|s) − min_i Q_i(s, a)) + action_l2 · mean a², a ~ π(·|s) reparameterised;
3. temperature ← mean(−log α · (log π(a|s) + target_entropy)), target entropy −d_a;
4. Polyak averaging of the critic targets.

An optional BC pre-training of the policy mean (:meth:`SAC.pretrain_step`) mirrors DDPG's, so both learners
can start from the demos; the deterministic policy used in evaluation is tanh(μ).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from surrol_data.algos.bc import BCConfig, BCPolicy
from surrol_data.algos.goal_inputs import GoalInputs
from surrol_data.algos.networks import DEFAULT_HIDDEN_SIZES, Critic, DeterministicActor, SquashedGaussianActor, soft_update
from surrol_data.algos.replay import EpisodeReplay, rng_from_tensor, rng_state_tensor


@dataclass
class SACConfig:
    hidden_sizes: tuple[int, ...] = DEFAULT_HIDDEN_SIZES
    actor_lr: float = 1e-4
    critic_lr: float = 1e-4
    alpha_lr: float = 1e-4
    initial_alpha: float = 0.1
    gamma: float = 0.99
    tau: float = 0.005
    batch_size: int = 128
    demo_batch_size: int = 128   # used by BC pre-training only
    action_l2: float = 1.0
    clip_target: bool = False
    clip_obs: float = 200.0
    norm_eps: float = 0.01
    norm_clip: float = 5.0


class SAC:
    uses_demos_in_loss = False  # demos reach SAC through the replay buffer (and the optional pre-training)

    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int, config: SACConfig, seed: int = 0):
        self.config = config
        self.act_dim = int(act_dim)
        self.inputs = GoalInputs(obs_dim, goal_dim, config.clip_obs, config.norm_eps, config.norm_clip)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.actor = SquashedGaussianActor(obs_dim, goal_dim, act_dim, config.hidden_sizes)
            self.critic1 = Critic(obs_dim, goal_dim, act_dim, config.hidden_sizes)
            self.critic2 = Critic(obs_dim, goal_dim, act_dim, config.hidden_sizes)
        self.critic1_target, self.critic2_target = copy.deepcopy(self.critic1), copy.deepcopy(self.critic2)
        self.log_alpha = torch.tensor(math.log(config.initial_alpha), requires_grad=True)
        self.target_entropy = -float(act_dim)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, fused=True)
        self.critic_opt = torch.optim.Adam([*self.critic1.parameters(), *self.critic2.parameters()],
                                           lr=config.critic_lr, fused=True)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=config.alpha_lr)
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)  # policy samples; checkpointed

    # ------------------------------------------------------------------ acting
    def act(self, obs: dict, explore: bool) -> np.ndarray:
        o = self.inputs.obs_norm.normalize(np.asarray(obs["observation"], np.float32))
        g = self.inputs.goal_norm.normalize(np.asarray(obs["desired_goal"], np.float32))
        with torch.no_grad():
            a, _ = self.actor(torch.from_numpy(o), torch.from_numpy(g), deterministic=not explore,
                              generator=self.generator)
        return a.numpy().astype(np.float32)

    def policy(self) -> BCPolicy:
        """tanh(μ) as a deterministic actor: the same hidden layers, the output layer's μ rows."""
        hidden = tuple(self.config.hidden_sizes)
        det = DeterministicActor(self.actor.obs_dim, self.actor.goal_dim, self.act_dim, hidden)
        state = {k: v.clone() for k, v in self.actor.state_dict().items()}
        last = f"net.{len(hidden) * 2}"
        state[f"{last}.weight"] = state[f"{last}.weight"][: self.act_dim]
        state[f"{last}.bias"] = state[f"{last}.bias"][: self.act_dim]
        det.load_state_dict(state)
        return BCPolicy(det, copy.deepcopy(self.inputs.obs_norm), copy.deepcopy(self.inputs.goal_norm),
                        BCConfig(hidden_sizes=hidden))

    # ------------------------------------------------------------------ learning
    def pretrain_step(self, demos: EpisodeReplay) -> float:
        b = demos.sample(self.config.demo_batch_size, self.rng)
        o, g = self.inputs(b["obs"], b["g"])
        mean_action, _ = self.actor(o, g, deterministic=True)
        loss = F.mse_loss(mean_action, torch.from_numpy(b["action"]))
        self.actor_opt.zero_grad(set_to_none=True)
        loss.backward()
        self.actor_opt.step()
        return loss.item()

    def finish_pretraining(self) -> None:
        pass  # SAC has no actor target

    def update(self, replay: EpisodeReplay, demos: EpisodeReplay | None = None) -> dict[str, float]:
        cfg = self.config
        b = replay.sample(cfg.batch_size, self.rng)
        o, g = self.inputs(b["obs"], b["g"])
        o2, _ = self.inputs(b["next_obs"], b["g"])
        a, r = torch.from_numpy(b["action"]), torch.from_numpy(b["reward"])
        alpha = self.log_alpha.exp().detach()

        # 1. critics
        with torch.no_grad():
            a2, logp2 = self.actor(o2, g, generator=self.generator)
            q_next = torch.min(self.critic1_target(o2, g, a2), self.critic2_target(o2, g, a2))
            y = r + cfg.gamma * (q_next - alpha * logp2)
            if cfg.clip_target:
                y = y.clamp(-1.0 / (1.0 - cfg.gamma), 0.0)
        q1, q2 = self.critic1(o, g, a), self.critic2(o, g, a)
        critic_loss = F.mse_loss(q1, y) + F.mse_loss(q2, y)
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()

        # 2. actor
        pi, logp = self.actor(o, g, generator=self.generator)
        for critic in (self.critic1, self.critic2):
            critic.requires_grad_(False)
        q_pi = torch.min(self.critic1(o, g, pi), self.critic2(o, g, pi))
        for critic in (self.critic1, self.critic2):
            critic.requires_grad_(True)
        actor_loss = (alpha * logp - q_pi).mean() + cfg.action_l2 * pi.pow(2).mean()
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_opt.step()

        # 3. temperature
        alpha_loss = -(self.log_alpha * (logp.detach() + self.target_entropy)).mean()
        self.alpha_opt.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_opt.step()

        # 4. targets
        soft_update(self.critic1_target, self.critic1, cfg.tau)
        soft_update(self.critic2_target, self.critic2, cfg.tau)
        return {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item(), "q": q1.mean().item(),
                "alpha": alpha.item(), "entropy": -logp.mean().item()}

    # ------------------------------------------------------------------ checkpointing
    _MODULES = ("actor", "critic1", "critic2", "critic1_target", "critic2_target", "actor_opt", "critic_opt", "alpha_opt")

    def state_dict(self) -> dict:
        state = {name: getattr(self, name).state_dict() for name in self._MODULES}
        state.update(inputs=self.inputs.state_dict(), log_alpha=self.log_alpha.detach().clone(),
                     rng=rng_state_tensor(self.rng), generator=self.generator.get_state())
        return state

    def load_state_dict(self, state: dict) -> None:
        self.inputs.load_state_dict(state["inputs"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        for name in self._MODULES:
            getattr(self, name).load_state_dict(state[name])
        self.rng = rng_from_tensor(state["rng"])
        self.generator.set_state(state["generator"])

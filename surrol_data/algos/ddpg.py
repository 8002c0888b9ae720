"""DDPG with hindsight replay, optionally with a behaviour-cloning term on demo batches (DDPG+BC+HER).

One learner, read top to bottom (reference §1.4, DEX's ``ddpgbc``; ``bc_weight = 0`` gives DEX's ``ddpg``):

per :meth:`DDPG.update` iteration

1. a HER batch from the **replay** buffer (agent and demo episodes):
   critic ← MSE(Q(s, a), clip(r + γ·Q'(s', π'(s')), −1/(1−γ), 0)),
   actor  ← −mean Q(s, π(s)) + action_l2 · mean π(s)²;
2. with demos and ``bc_weight > 0``, a HER batch from the **demo** buffer:
   the same critic step, then
   actor ← −mean[Q(s, π(s)) − λ·m(s)·‖π(s) − a_demo‖²/d_a] + action_l2 · mean π(s)²,
   where the Q-filter m(s) = 1[Q'(s, a_demo) ≥ Q'(s, π(s))] uses the target critic (all ones without it);
3. Polyak averaging of both targets with τ.

The offline→online warm start (``algo=ddpgbc_warm``; every option off in the paper-faithful ``ddpgbc``) adds
a critic pre-training on demo batches, a hold and ramp of the Q term (:func:`q_term_scale`), TD3+BC's |Q|
normalisation, one joint actor step, and ``filtered_bc``: on replay batches the actor also imitates the
batch's own actions where the target critic rates them above its own, −λ·1[Q'(s, a) > Q'(s, π(s))]·‖π(s) − a‖²/d_a
— an improvement step towards actions that were actually taken (and whose value the critic was trained on)
rather than along ∇ₐQ into actions it only extrapolates to.

The paper's BC pre-training (CoL-style, reference §2) is :meth:`DDPG.pretrain_step`, called by the run loop
before the online phase; it fits the actor alone to demo batches and then copies it into the target actor.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from surrol_data.algos.bc import BCConfig, BCPolicy
from surrol_data.algos.goal_inputs import GoalInputs
from surrol_data.algos.networks import DEFAULT_HIDDEN_SIZES, Critic, DeterministicActor, soft_update
from surrol_data.algos.replay import EpisodeReplay, rng_from_tensor, rng_state_tensor


@dataclass
class DDPGConfig:
    hidden_sizes: tuple[int, ...] = DEFAULT_HIDDEN_SIZES
    actor_lr: float = 1e-3
    critic_lr: float = 1e-3
    gamma: float = 0.99
    tau: float = 0.005               # Polyak rate, applied after every update iteration
    batch_size: int = 128            # replay batch
    demo_batch_size: int = 128       # demo batch (used when bc_weight > 0 and there are demos)
    bc_weight: float = 5.0           # λ; 0 turns DDPG+BC into plain DDPG+HER
    q_filter: bool = True
    action_l2: float = 1.0
    clip_target: bool = True         # clamp the TD target to [−1/(1−γ), 0], the range of sparse −1/0 returns
    noise_eps: float = 0.1           # Gaussian exploration σ (in action units)
    random_eps: float = 0.0          # probability of a uniform random action (baselines' ε; DEX uses 0)
    clip_obs: float = 200.0
    norm_eps: float = 0.01
    norm_clip: float = 5.0
    # offline→online warm start (all 0: the paper-faithful DDPG+BC+HER). The untrained critic's gradient
    # drags a BC-pre-trained actor off the demos in the first online epochs; these keep it on them:
    critic_pretrain_steps: int = 0   # after BC: TD steps of the critic on demo batches, bootstrapping through π
    actor_hold_updates: int = 0      # first online updates: the actor learns from the BC term only (no Q term)
    q_ramp_updates: int = 0          # then the Q term's weight rises linearly from 0 to 1 over this many updates
    q_normalize: bool = False        # divide the Q term by the batch's mean |Q| (TD3+BC): the BC term keeps its
                                     # weight whatever the scale of the returns (|Q| reaches 1/(1−γ) = 100 here)
    joint_actor_step: bool = False   # one actor step on replay + demo losses together: Adam rescales a step's
                                     # gradient, so a pure-Q replay step moves the actor at full speed whatever
                                     # its weight; only in a joint step do the Q weight and the BC term compete
    freeze_normalizer: bool = False  # online data no longer moves the obs/goal statistics: the BC actor keeps
                                     # the inputs it was trained on (they are the demos' statistics from then on)
    filtered_bc: bool = False        # the actor's improvement step is BC towards the replay batch's own actions
                                     # where the critic rates them above the actor's (binary advantage filter),
                                     # weighted by q_term_scale, instead of −Q: no step along ∇ₐQ at all
    online_actor_lr: float = 0.0     # the actor's learning rate in online updates (0: actor_lr throughout); BC
                                     # pre-training fits the demos at actor_lr, online steps then fine-tune it
    probe: bool = False              # log per epoch how far the learner has moved from its BC start (warm_probe)


def set_online_actor_lr(optimizer: torch.optim.Optimizer, config: DDPGConfig) -> None:
    """Before an online update: the actor's optimiser at ``online_actor_lr`` where one is set (idempotent, so it
    holds after a resume, whatever learning rate the saved optimiser state carried)."""
    if config.online_actor_lr > 0:
        for group in optimizer.param_groups:
            group["lr"] = config.online_actor_lr


def q_term_scale(online_updates: int, config: DDPGConfig) -> float:
    """Weight of the Q term in the actor loss at online update number ``online_updates`` (0-based)."""
    u = online_updates - config.actor_hold_updates
    if u < 0:
        return 0.0
    if config.q_ramp_updates <= 0:
        return 1.0
    return min(1.0, (u + 1) / config.q_ramp_updates)


class DDPG:
    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int, config: DDPGConfig, seed: int = 0):
        self.config = config
        self.act_dim = int(act_dim)
        self.inputs = GoalInputs(obs_dim, goal_dim, config.clip_obs, config.norm_eps, config.norm_clip)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.actor = DeterministicActor(obs_dim, goal_dim, act_dim, config.hidden_sizes)
            self.critic = Critic(obs_dim, goal_dim, act_dim, config.hidden_sizes)
        self.actor_target = copy.deepcopy(self.actor)
        self.critic_target = copy.deepcopy(self.critic)
        # fused Adam: one kernel for all parameters, 3x cheaper than the default per-tensor loop on CPU
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr, fused=True)
        self.rng = np.random.default_rng(seed)  # batches and exploration noise; checkpointed
        self.uses_demos_in_loss = config.bc_weight > 0
        self.online_updates = 0  # drives the actor hold / Q-term ramp; checkpointed
        self.reference = None    # (actor, inputs) frozen at the end of BC pre-training, with config.probe

    # ------------------------------------------------------------------ acting
    def act(self, obs: dict, explore: bool) -> np.ndarray:
        """Actions for a batch of obs dicts (arrays (B, dim)); Gaussian noise and ε-random actions when exploring."""
        o = self.inputs.obs_norm.normalize(np.asarray(obs["observation"], np.float32))
        g = self.inputs.goal_norm.normalize(np.asarray(obs["desired_goal"], np.float32))
        with torch.no_grad():
            a = self.actor(torch.from_numpy(o), torch.from_numpy(g)).numpy()
        if explore:
            cfg = self.config
            a = np.clip(a + cfg.noise_eps * self.rng.standard_normal(a.shape), -1.0, 1.0)
            if cfg.random_eps > 0:
                random = self.rng.random(a.shape[:-1]) < cfg.random_eps
                a[random] = self.rng.uniform(-1.0, 1.0, (int(random.sum()), self.act_dim))
        return a.astype(np.float32)

    def policy(self) -> BCPolicy:
        """The deterministic actor as a stand-alone policy (what evaluation and ``surrol-data eval`` load)."""
        return BCPolicy(copy.deepcopy(self.actor), copy.deepcopy(self.inputs.obs_norm),
                        copy.deepcopy(self.inputs.goal_norm), BCConfig(hidden_sizes=tuple(self.config.hidden_sizes)))

    # ------------------------------------------------------------------ learning
    def pretrain_step(self, demos: EpisodeReplay) -> float:
        """One BC step of the actor on a HER-relabelled demo batch; targets follow in :meth:`finish_pretraining`."""
        b = demos.sample(self.config.demo_batch_size, self.rng)
        o, g = self.inputs(b["obs"], b["g"])
        loss = F.mse_loss(self.actor(o, g), torch.from_numpy(b["action"]))
        self.actor_opt.zero_grad(set_to_none=True)
        loss.backward()
        self.actor_opt.step()
        return loss.item()

    def finish_pretraining(self) -> None:
        self.actor_target.load_state_dict(self.actor.state_dict())
        if self.config.probe:  # the BC start, with the statistics it was trained on, for warm_probe
            self.reference = (copy.deepcopy(self.actor).requires_grad_(False), copy.deepcopy(self.inputs))
        if self.config.freeze_normalizer:
            self.inputs.frozen = True

    def pretrain_critic_step(self, demos: EpisodeReplay) -> float:
        """Offline critic warm-up: a TD step on a demo batch, bootstrapping through the pre-trained actor."""
        loss, _ = self._critic_step(self._tensors(demos.sample(self.config.demo_batch_size, self.rng)))
        soft_update(self.critic_target, self.critic, self.config.tau)
        return loss

    def update(self, replay: EpisodeReplay, demos: EpisodeReplay | None) -> dict[str, float]:
        cfg = self.config
        set_online_actor_lr(self.actor_opt, cfg)
        # 1. replay batch
        scale = q_term_scale(self.online_updates, cfg)
        batch = self._tensors(replay.sample(cfg.batch_size, self.rng))
        critic_loss, q = self._critic_step(batch)
        metrics = {"critic_loss": critic_loss, "q": q}
        with_demos = demos is not None and self.uses_demos_in_loss
        if with_demos and cfg.joint_actor_step:
            demo_batch = self._tensors(demos.sample(cfg.demo_batch_size, self.rng))
            self._critic_step(demo_batch)
            metrics.update(self._actor_step([(batch, False), (demo_batch, True)], scale))
        else:
            if scale > 0:  # while the actor is held, the replay batch trains the critic only
                metrics.update(self._actor_step([(batch, False)], scale))
            # 2. demo batch
            if with_demos:
                demo_batch = self._tensors(demos.sample(cfg.demo_batch_size, self.rng))
                self._critic_step(demo_batch)
                metrics.update({k: v for k, v in self._actor_step([(demo_batch, True)], scale).items()
                                if k != "actor_loss"})
        # 3. targets
        soft_update(self.actor_target, self.actor, cfg.tau)
        soft_update(self.critic_target, self.critic, cfg.tau)
        self.online_updates += 1
        return metrics

    def _tensors(self, b: dict) -> dict[str, torch.Tensor]:
        o, g = self.inputs(b["obs"], b["g"])
        o2, _ = self.inputs(b["next_obs"], b["g"])
        return {"o": o, "g": g, "o2": o2, "a": torch.from_numpy(b["action"]), "r": torch.from_numpy(b["reward"])}

    def _critic_step(self, b: dict[str, torch.Tensor]) -> tuple[float, float]:
        cfg = self.config
        with torch.no_grad():
            y = b["r"] + cfg.gamma * self.critic_target(b["o2"], b["g"], self.actor_target(b["o2"], b["g"]))
            if cfg.clip_target:
                y = y.clamp(-1.0 / (1.0 - cfg.gamma), 0.0)
        q = self.critic(b["o"], b["g"], b["a"])
        loss = F.mse_loss(q, y)
        self.critic_opt.zero_grad(set_to_none=True)
        loss.backward()
        self.critic_opt.step()
        return loss.item(), q.mean().item()

    def _actor_step(self, parts: list[tuple[dict[str, torch.Tensor], bool]], q_scale: float = 1.0) -> dict[str, float]:
        """One Adam step of the actor on the summed losses of ``parts`` ((batch, with BC term) pairs);
        ``actor_loss`` reports the first part's loss."""
        losses, out = [], {}
        for b, bc in parts:
            loss, extra = self._actor_loss(b, q_scale, bc)
            losses.append(loss)
            out.update(extra)
        self.actor_opt.zero_grad(set_to_none=True)
        sum(losses).backward()
        self.actor_opt.step()
        return {"actor_loss": losses[0].item(), **out}

    def _actor_loss(self, b: dict[str, torch.Tensor], q_scale: float, bc: bool) -> tuple[torch.Tensor, dict]:
        cfg = self.config
        pi = self.actor(b["o"], b["g"])
        if q_scale > 0 and not cfg.filtered_bc:
            # the critic is a fixed function here: skipping its weight gradients saves a third of the backward pass
            self.critic.requires_grad_(False)
            objective = self.critic(b["o"], b["g"], pi)
            self.critic.requires_grad_(True)
            if cfg.q_normalize:
                objective = objective / objective.detach().abs().mean().clamp_min(1e-3)
            if q_scale != 1.0:
                objective = q_scale * objective
        else:
            objective = torch.zeros(pi.shape[:-1])
        out = {}
        if cfg.filtered_bc and not bc:
            # imitate the batch's own actions where the critic rates them above the actor's: a step towards
            # actions that were taken, never towards one the critic only extrapolates to
            with torch.no_grad():
                better = (self.critic_target(b["o"], b["g"], b["a"]) > self.critic_target(b["o"], b["g"], pi)).float()
            objective = objective - q_scale * cfg.bc_weight * better * (pi - b["a"]).pow(2).sum(-1) / self.act_dim
            out = {"advantage_pass": better.mean().item()}
        if bc:
            per_sample_bc = (pi - b["a"]).pow(2).sum(-1) / self.act_dim
            if cfg.q_filter:
                with torch.no_grad():
                    mask = (self.critic_target(b["o"], b["g"], b["a"])
                            >= self.critic_target(b["o"], b["g"], pi.detach())).float()
            else:
                mask = torch.ones_like(per_sample_bc)
            objective = objective - cfg.bc_weight * mask * per_sample_bc
            out = {"bc_loss": per_sample_bc.mean().item(), "q_filter_pass": mask.mean().item()}
        return -objective.mean() + cfg.action_l2 * pi.pow(2).mean(), out

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict:
        return {"inputs": self.inputs.state_dict(), "actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                "actor_target": self.actor_target.state_dict(), "critic_target": self.critic_target.state_dict(),
                "actor_opt": self.actor_opt.state_dict(), "critic_opt": self.critic_opt.state_dict(),
                "rng": rng_state_tensor(self.rng), "online_updates": self.online_updates,
                **({"reference_actor": self.reference[0].state_dict(), "reference_inputs": self.reference[1].state_dict()}
                   if self.reference is not None else {})}

    def load_state_dict(self, state: dict) -> None:
        self.inputs.load_state_dict(state["inputs"])
        for name in ("actor", "critic", "actor_target", "critic_target", "actor_opt", "critic_opt"):
            getattr(self, name).load_state_dict(state[name])
        self.rng = rng_from_tensor(state["rng"])
        self.online_updates = int(state.get("online_updates", 0))
        if "reference_actor" in state:
            actor, inputs = copy.deepcopy(self.actor).requires_grad_(False), copy.deepcopy(self.inputs)
            actor.load_state_dict(state["reference_actor"])
            inputs.load_state_dict(state["reference_inputs"])
            self.reference = (actor, inputs)


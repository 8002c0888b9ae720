"""DDPG(+BC)+HER for several runs at once: M members' networks stacked, one batched matmul per layer.

Why: one 3×256 MLP update at batch 128 is too small to keep a core busy — most of a single run's update
time is Python and per-call overhead (57 updates/s where the FLOPs allow several hundred). Stacking the
weights of M runs into ``(M, out, in)`` tensors makes every layer one ``torch.baddbmm`` over all members,
every optimiser step one fused Adam call and every target update one ``_foreach_lerp_``, so the overhead
is paid once per update for all members.

Each member is still its own run, exactly as :class:`~surrol_data.algos.ddpg.DDPG` would be:

* initial weights: member i is built by ``DDPG(..., seed=seeds[i])`` and its weights copied in;
* its own normalisers (``inputs[i]``) and its own generator (``rngs[i]``), drawn in the same order as a
  single run draws (replay batch, then demo batch), so a member samples the very batches its single run
  would sample;
* losses are summed over members of per-member means: the gradient of member i is its own loss's
  gradient, and Adam is elementwise, so the stacked optimiser is M independent optimisers;
* :meth:`member_state_dict` / :meth:`load_member_state_dict` speak the single run's ``DDPG.state_dict``
  format, so a member's checkpoint is an ordinary run checkpoint.

What differs from M single runs is floating-point rounding only (batched vs plain matmul kernels).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from surrol_data.algos.bc import BCConfig, BCPolicy
from surrol_data.algos.ddpg import DDPG, DDPGConfig, q_term_scale, set_online_actor_lr
from surrol_data.algos.env_pool import PolicySnapshot, explored_action
from surrol_data.algos.networks import DeterministicActor
from surrol_data.algos.replay import EpisodeReplay, rng_from_tensor, rng_state_tensor


class StackedMLP(nn.Module):
    """M copies of one :func:`~surrol_data.algos.networks.mlp` architecture, evaluated on ``(M, B, in)`` inputs.

    Parameters are ordered as ``nn.Sequential.parameters()`` orders a single MLP's (w0, b0, w1, b1, …), each
    with a leading member dimension, so optimiser states convert one-to-one. Weights are stored transposed,
    ``(M, in, out)``, so that every layer is ``baddbmm(b, x, w)`` on contiguous operands: with the single run's
    ``(out, in)`` layout the forward and backward passes copied transposed views at every layer (~11 % of an
    update's CPU time); :meth:`member_state` converts back.
    """

    def __init__(self, members: list[nn.Sequential]):
        super().__init__()
        per_member = [[layer for layer in seq if isinstance(layer, nn.Linear)] for seq in members]
        self.n_layers = len(per_member[0])
        # index k of a Linear inside the Sequential (Linear, ReLU, Linear, …): 2k
        params = []
        for k in range(self.n_layers):
            params.append(nn.Parameter(torch.stack([m[k].weight.detach().t() for m in per_member]).contiguous()))
            params.append(nn.Parameter(torch.stack([m[k].bias.detach().clone() for m in per_member])))
        self.params = nn.ParameterList(params)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for k in range(self.n_layers):
            w, b = self.params[2 * k], self.params[2 * k + 1]
            x = torch.baddbmm(b.unsqueeze(1), x, w)
            if k < self.n_layers - 1:
                x = torch.relu(x)
        return x

    def member_state(self, i: int, prefix: str = "net.") -> dict[str, torch.Tensor]:
        out = {}
        for k in range(self.n_layers):
            out[f"{prefix}{2 * k}.weight"] = self.params[2 * k][i].detach().t().contiguous()
            out[f"{prefix}{2 * k}.bias"] = self.params[2 * k + 1][i].detach().clone()
        return out

    def load_member_state(self, i: int, state: dict[str, torch.Tensor], prefix: str = "net.") -> None:
        with torch.no_grad():
            for k in range(self.n_layers):
                self.params[2 * k][i].copy_(state[f"{prefix}{2 * k}.weight"].t())
                self.params[2 * k + 1][i].copy_(state[f"{prefix}{2 * k}.bias"])


class EnsembleDDPG:
    def __init__(self, obs_dim: int, goal_dim: int, act_dim: int, config: DDPGConfig, seeds: list[int]):
        if not seeds:
            raise ValueError("an ensemble needs at least one member seed")
        self.config, self.act_dim, self.seeds = config, int(act_dim), list(seeds)
        self.obs_dim, self.goal_dim = int(obs_dim), int(goal_dim)
        singles = [DDPG(obs_dim, goal_dim, act_dim, config, seed=s) for s in seeds]  # the single runs' inits
        self.inputs = [m.inputs for m in singles]
        self.rngs = [m.rng for m in singles]
        self.online_updates = [0] * len(seeds)
        self.actor = StackedMLP([m.actor.net for m in singles])
        self.critic = StackedMLP([m.critic.net for m in singles])
        self.actor_target = StackedMLP([m.actor.net for m in singles])
        self.critic_target = StackedMLP([m.critic.net for m in singles])
        for net in (self.actor_target, self.critic_target):
            net.requires_grad_(False)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr, fused=True)
        self.uses_demos_in_loss = config.bc_weight > 0

    def __len__(self) -> int:
        return len(self.seeds)

    # ------------------------------------------------------------------ networks on (M, B, ·)
    def _pi(self, net: StackedMLP, o: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        return torch.tanh(net(torch.cat([o, g], -1)))

    def _q(self, net: StackedMLP, o: torch.Tensor, g: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return net(torch.cat([o, g, a], -1)).squeeze(-1)

    # ------------------------------------------------------------------ acting
    def act(self, obs: list[dict], explore: bool) -> list:
        """Actions of every member for its own batch of obs dicts (arrays (B, dim), same B for all)."""
        o = torch.stack([torch.from_numpy(self.inputs[i].obs_norm.normalize(ob["observation"])) for i, ob in enumerate(obs)])
        g = torch.stack([torch.from_numpy(self.inputs[i].goal_norm.normalize(ob["desired_goal"]))
                         for i, ob in enumerate(obs)])
        with torch.no_grad():
            a = self._pi(self.actor, o, g).numpy()
        out = []
        for i in range(len(self)):
            e = self.exploration(i, 1, a.shape[1]) if explore else None
            out.append(explored_action(a[i], {k: v if v is None else v.swapaxes(0, 1) for k, v in e.items()}
                                       if e else None, 0))
        return out

    def exploration(self, i: int, steps: int, n_envs: int) -> dict:
        """Member i's exploration for ``steps`` steps of ``n_envs`` envs, drawn from its generator in the order
        :meth:`DDPG.act` draws them step by step: ``noise`` (T, n, A) (σ·N(0, 1)), and with ``random_eps``
        the ``replace`` mask (T, n) and the uniform ``random`` actions (T, n, A) that replace those entries."""
        cfg, rng, shape = self.config, self.rngs[i], (steps, n_envs, self.act_dim)
        if cfg.random_eps <= 0:  # one draw of T·n·A normals is the same stream as T draws of n·A
            return {"noise": cfg.noise_eps * rng.standard_normal(shape), "replace": None, "random": None}
        noise, replace, random = np.zeros(shape), np.zeros(shape[:2], bool), np.zeros(shape, np.float64)
        for t in range(steps):
            noise[t] = cfg.noise_eps * rng.standard_normal(shape[1:])
            replace[t] = rng.random(n_envs) < cfg.random_eps
            random[t, replace[t]] = rng.uniform(-1.0, 1.0, (int(replace[t].sum()), self.act_dim))
        return {"noise": noise, "replace": replace, "random": random}

    def snapshot(self) -> PolicySnapshot:
        """Every member's actor and normaliser statistics as arrays, for env workers that act on their own."""
        with torch.no_grad():
            weights = [self.actor.params[2 * k].numpy().copy() for k in range(self.actor.n_layers)]   # (M, in, out)
            biases = [self.actor.params[2 * k + 1].numpy().copy() for k in range(self.actor.n_layers)]
        norms = [(x.obs_norm, x.goal_norm) for x in self.inputs]
        return PolicySnapshot(weights, biases, np.stack([o.mean for o, _ in norms]), np.stack([o.std for o, _ in norms]),
                              np.stack([g.mean for _, g in norms]), np.stack([g.std for _, g in norms]),
                              norms[0][0].clip)

    def policy(self, i: int) -> BCPolicy:
        """Member i's deterministic actor as the stand-alone policy a single run saves."""
        actor = DeterministicActor(self.obs_dim, self.goal_dim, self.act_dim, self.config.hidden_sizes)
        actor.load_state_dict(self.actor.member_state(i))
        import copy

        return BCPolicy(actor, copy.deepcopy(self.inputs[i].obs_norm), copy.deepcopy(self.inputs[i].goal_norm),
                        BCConfig(hidden_sizes=tuple(self.config.hidden_sizes)))

    # ------------------------------------------------------------------ learning
    def _batch(self, buffers: list[EpisodeReplay], size: int) -> dict[str, torch.Tensor]:
        parts = []
        for i, buf in enumerate(buffers):
            b = buf.sample(size, self.rngs[i])
            o, g = self.inputs[i](b["obs"], b["g"])
            o2, _ = self.inputs[i](b["next_obs"], b["g"])
            parts.append((o, g, o2, torch.from_numpy(b["action"]), torch.from_numpy(b["reward"])))
        return {k: torch.stack([p[j] for p in parts]) for j, k in enumerate(("o", "g", "o2", "a", "r"))}

    def pretrain_step(self, demos: list[EpisodeReplay]) -> list[float]:
        """One BC step of every member's actor on its own demo batch."""
        b = self._batch(demos, self.config.demo_batch_size)
        per_member = (self._pi(self.actor, b["o"], b["g"]) - b["a"]).pow(2).mean((1, 2))
        self.actor_opt.zero_grad(set_to_none=True)
        per_member.sum().backward()
        self.actor_opt.step()
        return per_member.tolist()

    def finish_pretraining(self) -> None:
        with torch.no_grad():
            for t, s in zip(self.actor_target.parameters(), self.actor.parameters()):
                t.copy_(s)
        if getattr(self.config, "freeze_normalizer", False):  # as DDPG.finish_pretraining: keep the demo statistics
            for inputs in self.inputs:
                inputs.frozen = True

    def pretrain_critic_step(self, demos: list[EpisodeReplay]) -> list[float]:
        """Offline critic warm-up: a TD step on a demo batch, bootstrapping through the pre-trained actor."""
        b = self._batch(demos, self.config.demo_batch_size)
        loss, _ = self._critic_step(b)
        torch._foreach_lerp_(list(self.critic_target.parameters()), list(self.critic.parameters()), self.config.tau)
        return loss.tolist()

    def update(self, replays: list[EpisodeReplay], demos: list[EpisodeReplay] | None) -> list[dict[str, float]]:
        """One update iteration of every member (DDPG.update's steps, batched); per-member metrics."""
        cfg = self.config
        set_online_actor_lr(self.actor_opt, cfg)
        with_demos = demos is not None and self.uses_demos_in_loss
        # same draw order as DDPG.update: member i's replay batch, then its demo batch, from rngs[i]
        batch = self._batch(replays, cfg.batch_size)
        demo_batch = self._batch(demos, cfg.demo_batch_size) if with_demos else None
        if with_demos:  # the target nets do not change within an update: both batches' TD targets in one pass
            self._td_targets(batch, demo_batch)
        scale = q_term_scale(self.online_updates[0], cfg)  # members advance in lock step
        critic_loss, q = self._critic_step(batch)
        metrics = {"critic_loss": critic_loss, "q": q}
        if with_demos and cfg.joint_actor_step:
            self._critic_step(demo_batch)
            metrics.update(self._actor_step([(batch, False), (demo_batch, True)], scale))
        else:
            if scale > 0:
                metrics.update(self._actor_step([(batch, False)], scale))
            if with_demos:
                self._critic_step(demo_batch)
                metrics.update({k: v for k, v in self._actor_step([(demo_batch, True)], scale).items()
                                if k != "actor_loss"})
        torch._foreach_lerp_(list(self.actor_target.parameters()), list(self.actor.parameters()), cfg.tau)
        torch._foreach_lerp_(list(self.critic_target.parameters()), list(self.critic.parameters()), cfg.tau)
        self.online_updates = [u + 1 for u in self.online_updates]
        names = list(metrics)
        values = torch.stack([metrics[k] for k in names], 1).tolist()
        return [dict(zip(names, row)) for row in values]

    def _td_targets(self, *batches: dict[str, torch.Tensor]) -> None:
        """r + γ·Q'(s', π'(s')) (clipped) of every batch, as ``b["y"]``, in one forward pass of the target nets."""
        cfg = self.config
        o2, g = torch.cat([b["o2"] for b in batches], 1), torch.cat([b["g"] for b in batches], 1)
        with torch.no_grad():
            q_next = self._q(self.critic_target, o2, g, self._pi(self.actor_target, o2, g))
        for b, q in zip(batches, q_next.split([b["o2"].shape[1] for b in batches], 1)):
            y = b["r"] + cfg.gamma * q
            b["y"] = y.clamp(-1.0 / (1.0 - cfg.gamma), 0.0) if cfg.clip_target else y

    def _critic_step(self, b: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        if "y" not in b:
            self._td_targets(b)
        y = b["y"]
        q = self._q(self.critic, b["o"], b["g"], b["a"])
        per_member = (q - y).pow(2).mean(1)
        self.critic_opt.zero_grad(set_to_none=True)
        per_member.sum().backward()
        self.critic_opt.step()
        return per_member.detach(), q.detach().mean(1)

    def _actor_step(self, parts: list[tuple[dict[str, torch.Tensor], bool]], q_scale: float) -> dict[str, torch.Tensor]:
        """DDPG._actor_step for every member: one Adam step on the summed per-member losses of ``parts``."""
        losses, out = [], {}
        for b, bc in parts:
            loss, extra = self._actor_loss(b, q_scale, bc)
            losses.append(loss)
            out.update(extra)
        self.actor_opt.zero_grad(set_to_none=True)
        sum(losses).sum().backward()
        self.actor_opt.step()
        return {"actor_loss": losses[0].detach(), **out}

    def _actor_loss(self, b: dict[str, torch.Tensor], q_scale: float, bc: bool) -> tuple[torch.Tensor, dict]:
        """Per-member actor losses (M,) on one stacked batch."""
        cfg = self.config
        pi = self._pi(self.actor, b["o"], b["g"])
        out = {}
        filtered_bc = getattr(cfg, "filtered_bc", False)
        if q_scale > 0 and not filtered_bc:
            self.critic.requires_grad_(False)  # only the action gradient is needed, not the critic's weights'
            objective = self._q(self.critic, b["o"], b["g"], pi)
            self.critic.requires_grad_(True)
            if cfg.q_normalize:  # per member: each run's own mean |Q|
                objective = objective / objective.detach().abs().mean(1, keepdim=True).clamp_min(1e-3)
            if q_scale != 1.0:
                objective = q_scale * objective
        else:
            objective = torch.zeros(pi.shape[:-1])
        if filtered_bc and not bc:  # DDPG._actor_loss's filtered BC towards the replay batch's own actions
            with torch.no_grad():
                n = b["a"].shape[1]
                both = self._q(self.critic_target, b["o"].repeat(1, 2, 1), b["g"].repeat(1, 2, 1),
                               torch.cat([b["a"], pi.detach()], 1))
                better = (both[:, :n] > both[:, n:]).float()
            objective = objective - q_scale * cfg.bc_weight * better * (pi - b["a"]).pow(2).sum(-1) / self.act_dim
            out = {"advantage_pass": better.mean(1)}
        if bc:
            per_sample_bc = (pi - b["a"]).pow(2).sum(-1) / self.act_dim
            if cfg.q_filter:
                with torch.no_grad():  # Q'(s, a_demo) and Q'(s, π(s)) in one forward pass
                    n = b["a"].shape[1]
                    both = self._q(self.critic_target, b["o"].repeat(1, 2, 1), b["g"].repeat(1, 2, 1),
                                   torch.cat([b["a"], pi.detach()], 1))
                    mask = (both[:, :n] >= both[:, n:]).float()
            else:
                mask = torch.ones_like(per_sample_bc)
            objective = objective - cfg.bc_weight * mask * per_sample_bc
            out = {"bc_loss": per_sample_bc.detach().mean(1), "q_filter_pass": mask.mean(1)}
        return -objective.mean(1) + cfg.action_l2 * pi.pow(2).mean((1, 2)), out

    # ------------------------------------------------------------------ checkpointing (single-run format)
    def member_state_dict(self, i: int) -> dict:
        return {"inputs": self.inputs[i].state_dict(),
                "actor": self.actor.member_state(i), "critic": self.critic.member_state(i),
                "actor_target": self.actor_target.member_state(i), "critic_target": self.critic_target.member_state(i),
                "actor_opt": _member_opt_state(self.actor_opt, i), "critic_opt": _member_opt_state(self.critic_opt, i),
                "rng": rng_state_tensor(self.rngs[i]), "online_updates": self.online_updates[i]}

    def load_member_state_dict(self, i: int, state: dict) -> None:
        self.inputs[i].load_state_dict(state["inputs"])
        for name in ("actor", "critic", "actor_target", "critic_target"):
            getattr(self, name).load_member_state(i, state[name])
        _load_member_opt_state(self.actor_opt, i, state["actor_opt"])
        _load_member_opt_state(self.critic_opt, i, state["critic_opt"])
        self.rngs[i] = rng_from_tensor(state["rng"])
        self.online_updates[i] = int(state.get("online_updates", 0))


def _member_opt_state(opt: torch.optim.Adam, i: int) -> dict:
    """Member i's slice of a stacked Adam, as ``torch.optim.Adam.state_dict()`` of its single run."""
    params = opt.param_groups[0]["params"]
    state = {}
    for idx, p in enumerate(params):
        s = opt.state.get(p)
        if s:
            state[idx] = {"step": s["step"].clone(), "exp_avg": _single_layout(s["exp_avg"][i]),
                          "exp_avg_sq": _single_layout(s["exp_avg_sq"][i])}
    group = {k: v for k, v in opt.param_groups[0].items() if k != "params"}
    return {"state": state, "param_groups": [{**group, "params": list(range(len(params)))}]}


def _load_member_opt_state(opt: torch.optim.Adam, i: int, saved: dict) -> None:
    params = opt.param_groups[0]["params"]
    for idx, p in enumerate(params):
        s = saved["state"].get(idx)
        if s is None:
            continue
        mine = opt.state[p]
        if not mine:
            mine["step"] = torch.zeros((), dtype=torch.float32)
            mine["exp_avg"] = torch.zeros_like(p)
            mine["exp_avg_sq"] = torch.zeros_like(p)
        # members advance in lock step, so every member's Adam step count is the same
        mine["step"].copy_(s["step"])
        mine["exp_avg"][i].copy_(_single_layout(s["exp_avg"]))
        mine["exp_avg_sq"][i].copy_(_single_layout(s["exp_avg_sq"]))


def _single_layout(member_slice: torch.Tensor) -> torch.Tensor:
    """A weight's (in, out) member slice as the single run's (out, in), and back (biases unchanged)."""
    return member_slice.t().contiguous() if member_slice.dim() == 2 else member_slice.clone()

"""What the online phase does to a BC-pre-trained DDPG learner, measured on fixed demo states every epoch.

The offline→online collapse (success of the BC actor falling to 0 in the first online epochs) has several
candidate causes; each column of :func:`probe` isolates one (all on the same demo states, true goals):

* ``probe_q_demo`` / ``probe_q_pi``: the critic's Q of the demo action and of the actor's action; a critic that
  rates the actor's actions above the demonstrator's (``probe_q_pi_over_demo`` > 0) pulls the actor off them;
* ``probe_pi_to_bc`` / ``probe_pi_to_demo``: RMS action distance of the actor from the BC actor it started as
  (with that actor's own normaliser) and from the demo actions; ``probe_bc_to_demo`` is the BC actor's own error;
* ``probe_norm_input_shift`` / ``probe_norm_action_shift``: how far the running obs/goal normaliser has moved
  the network inputs since BC pre-training (RMS, in normalised units), and how far that shift alone moves the
  BC actor's actions — the normaliser drift hypothesis, separated from any weight change.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch


def probe_states(trajectories: Sequence, stride: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(obs, goal, action) of every ``stride``-th demo step: the fixed states every epoch is probed on."""
    if not trajectories:
        raise ValueError("probe_states needs demo trajectories")
    obs = np.concatenate([t.observation[:-1][::stride] for t in trajectories]).astype(np.float32)
    goal = np.concatenate([t.desired_goal[:-1][::stride] for t in trajectories]).astype(np.float32)
    action = np.concatenate([t.action[::stride] for t in trajectories]).astype(np.float32)
    return obs, goal, action


def _rms(x: torch.Tensor) -> float:
    return float(x.pow(2).mean().sqrt())


@torch.no_grad()
def probe(learner, obs: np.ndarray, goal: np.ndarray, action: np.ndarray) -> dict[str, float]:
    """The probe columns for a DDPG learner whose ``reference`` (BC actor, its inputs) was kept."""
    if learner.reference is None:
        raise ValueError("probe needs the learner's BC reference: build it with probe=true and finish pre-training")
    bc_actor, bc_inputs = learner.reference
    o, g = learner.inputs(obs, goal)
    o_bc, g_bc = bc_inputs(obs, goal)
    a = torch.from_numpy(action)
    pi, pi_bc, pi_bc_now = learner.actor(o, g), bc_actor(o_bc, g_bc), bc_actor(o, g)
    q_demo, q_pi = learner.critic(o, g, a), learner.critic(o, g, pi)
    return {
        "probe_q_demo": float(q_demo.mean()), "probe_q_pi": float(q_pi.mean()),
        "probe_q_pi_over_demo": float((q_pi > q_demo).float().mean()),
        "probe_pi_to_bc": _rms(pi - pi_bc), "probe_pi_to_demo": _rms(pi - a), "probe_bc_to_demo": _rms(pi_bc - a),
        "probe_norm_input_shift": _rms(torch.cat([o - o_bc, g - g_bc], -1)),
        "probe_norm_action_shift": _rms(pi_bc_now - pi_bc),
    }

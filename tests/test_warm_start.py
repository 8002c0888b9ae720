"""The offline→online warm start (algo=ddpgbc_warm): the advantage-filtered BC term, the probe, a short run."""

import json

import numpy as np
import pytest
import torch

from surrol_data.algos.ddpg import DDPG, DDPGConfig
from surrol_data.algos.warm_probe import probe, probe_states

REACH = "SurRoL/NeedleReach-v0"


def _batch(n: int = 64, seed: int = 0) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return {"o": torch.randn(n, 7, generator=gen), "g": torch.randn(n, 3, generator=gen),
            "o2": torch.randn(n, 7, generator=gen), "a": torch.zeros(n, 5), "r": torch.full((n,), -1.0)}


class FixedCritic(torch.nn.Module):
    """Q(s, a) = −‖a − best(s)‖²: a critic whose preferred actions the test chooses."""

    def __init__(self, best: torch.Tensor):
        super().__init__()
        self.best = best

    def forward(self, o, g, a):
        return -(a - self.best).pow(2).sum(-1)


def _agent_and_batch(taken_is_better: bool, **params):
    cfg = DDPGConfig(hidden_sizes=(32,), actor_lr=1e-2, bc_weight=5.0, action_l2=0.0, q_filter=False, **params)
    agent, b = DDPG(7, 3, 5, cfg, seed=0), _batch()
    with torch.no_grad():
        pi0 = agent.actor(b["o"], b["g"])
    preferred = (pi0 + 0.3).clamp(-1, 1)                                 # what the critic rates highest
    b["a"] = preferred if taken_is_better else (pi0 - 0.3).clamp(-1, 1)  # what the batch's episodes did
    agent.critic = agent.critic_target = FixedCritic(preferred)
    return agent, b, pi0, preferred


def _distance(agent, b, target):
    with torch.no_grad():
        return (agent.actor(b["o"], b["g"]) - target).pow(2).mean().item()


@pytest.mark.parametrize("taken_is_better", [True, False])
def test_filtered_bc_moves_the_actor_only_towards_taken_actions_the_critic_prefers(taken_is_better):
    agent, b, pi0, preferred = _agent_and_batch(taken_is_better, filtered_bc=True)
    before = [p.clone() for p in agent.actor.parameters()]
    for _ in range(30):
        out = agent._actor_step([(b, False)], q_scale=1.0)
    if taken_is_better:  # every sample passes the filter and the actor walks to the taken actions
        assert out["advantage_pass"] == 1.0
        assert _distance(agent, b, preferred) < 0.25 * (pi0 - preferred).pow(2).mean().item()
    else:  # taken actions rated below the actor's own: no sample passes, the actor stays exactly where it is
        assert out["advantage_pass"] == 0.0
        assert all(torch.equal(a, p) for a, p in zip(before, agent.actor.parameters()))
    # the warm start's hold (scale 0) switches the filtered term off like the Q term
    held, b, _, _ = _agent_and_batch(True, filtered_bc=True)
    before = [p.clone() for p in held.actor.parameters()]
    held._actor_step([(b, False)], q_scale=0.0)
    assert all(torch.equal(a, p) for a, p in zip(before, held.actor.parameters()))


def test_without_the_filter_the_actor_follows_the_critic_to_actions_nobody_took():
    """The contrast that gives the test above its meaning: DDPG's −Q step moves the actor to the critic's
    preferred actions although the batch only holds worse ones — the offline→online collapse in small."""
    agent, b, pi0, preferred = _agent_and_batch(False)
    for _ in range(30):
        agent._actor_step([(b, False)], q_scale=1.0)
    assert _distance(agent, b, preferred) < 0.25 * (pi0 - preferred).pow(2).mean().item()


def test_frozen_normaliser_keeps_the_demo_statistics_online():
    rng = np.random.default_rng(0)
    agent = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,), freeze_normalizer=True), seed=0)
    agent.inputs.update(rng.normal(size=(50, 7)), rng.normal(size=(50, 3)))
    agent.finish_pretraining()
    mean = agent.inputs.obs_norm.mean.copy()
    agent.inputs.update(rng.normal(size=(50, 7)) + 3.0, rng.normal(size=(50, 3)))
    np.testing.assert_array_equal(agent.inputs.obs_norm.mean, mean)
    restored = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,)), seed=0)
    restored.load_state_dict(agent.state_dict())
    assert restored.inputs.frozen
    paper = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,)), seed=0)  # ddpgbc: statistics keep moving
    paper.finish_pretraining()
    paper.inputs.update(rng.normal(size=(50, 7)) + 3.0, rng.normal(size=(50, 3)))
    assert paper.inputs.obs_norm.mean.mean() > 1.0


def _replay(seed: int):
    from surrol_data.algos.replay import EpisodeReplay

    reward = lambda ag, g: -(np.linalg.norm(ag - g, axis=-1) > 0.5).astype(np.float32)  # noqa: E731
    buf = EpisodeReplay(8, 20, 7, 3, 5, reward, 4, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(4):
        buf.add_episode(rng.normal(size=(21, 7)), rng.normal(size=(21, 3)), rng.normal(size=(20, 3)),
                        rng.uniform(-1, 1, (20, 5)))
    return buf


def test_online_updates_fine_tune_the_actor_at_their_own_learning_rate_also_after_a_resume():
    from surrol_data.algos.ensemble import EnsembleDDPG

    cfg = DDPGConfig(hidden_sizes=(16,), actor_lr=1e-3, online_actor_lr=1e-4, bc_weight=5.0)
    lr = lambda opt: opt.param_groups[0]["lr"]  # noqa: E731
    agent = DDPG(7, 3, 5, cfg, seed=0)
    agent.pretrain_step(_replay(1))
    assert lr(agent.actor_opt) == 1e-3        # BC pre-training fits the demos at actor_lr
    agent.finish_pretraining()
    agent.update(_replay(2), _replay(1))
    assert lr(agent.actor_opt) == 1e-4 and lr(agent.critic_opt) == 1e-3
    restored = DDPG(7, 3, 5, cfg, seed=0)
    restored.load_state_dict(agent.state_dict())
    restored.update(_replay(2), _replay(1))
    assert lr(restored.actor_opt) == 1e-4
    ensemble = EnsembleDDPG(7, 3, 5, cfg, [0, 1])
    ensemble.pretrain_step([_replay(1), _replay(3)])
    assert lr(ensemble.actor_opt) == 1e-3
    ensemble.update([_replay(2), _replay(4)], [_replay(1), _replay(3)])
    assert lr(ensemble.actor_opt) == 1e-4
    paper = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,)), seed=0)   # unset: actor_lr throughout
    paper.update(_replay(2), _replay(1))
    assert lr(paper.actor_opt) == 1e-3


class _Traj:
    def __init__(self, rng, n=20):
        self.observation = rng.normal(size=(n + 1, 7)).astype(np.float32)
        self.desired_goal = rng.normal(size=(n + 1, 3)).astype(np.float32)
        self.action = rng.uniform(-1, 1, (n, 5)).astype(np.float32)


def test_probe_separates_weight_changes_from_normaliser_drift():
    rng = np.random.default_rng(0)
    obs, goal, action = probe_states([_Traj(rng), _Traj(rng)], stride=5)
    assert obs.shape == (8, 7) and goal.shape == (8, 3) and action.shape == (8, 5)
    agent = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,), probe=True), seed=0)
    agent.inputs.update(obs, goal)
    with pytest.raises(ValueError, match="probe=true"):
        probe(agent, obs, goal, action)
    agent.finish_pretraining()
    start = probe(agent, obs, goal, action)
    assert start["probe_pi_to_bc"] == 0.0 and start["probe_norm_input_shift"] == 0.0
    assert start["probe_pi_to_demo"] == pytest.approx(start["probe_bc_to_demo"])
    agent.inputs.update(obs + 3.0, goal)  # online data elsewhere: the statistics move, the weights do not
    drift = probe(agent, obs, goal, action)
    assert drift["probe_norm_input_shift"] > 0.5 and drift["probe_norm_action_shift"] > 0
    assert drift["probe_pi_to_bc"] == pytest.approx(drift["probe_norm_action_shift"])
    # the reference survives a checkpoint round trip
    restored = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,), probe=True), seed=1)
    restored.load_state_dict(agent.state_dict())
    assert probe(restored, obs, goal, action) == drift


@pytest.fixture(scope="module")
def reach_demos(tmp_path_factory):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("demos") / "NeedleReach_script"
    collect_script("NeedleReach", 4, root, progress=False)
    return root


def test_warm_algo_runs_the_smoke_experiment_with_its_pieces_logged(tmp_path, reach_demos, monkeypatch):
    from hydra import compose, initialize_config_dir

    from surrol_data.algos.train import train
    from surrol_data.train_app import config_dir, to_train_config

    monkeypatch.chdir(tmp_path)
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = to_train_config(compose("config", [
            "algo=ddpgbc_warm", "task=NeedleReach", "demos=script", "demos.num=4", f"demos_root={reach_demos.parent}",
            "experiment=smoke", "algo.offline_steps=20", "algo.params.critic_pretrain_steps=20",
            "algo.params.hidden_sizes=[32,32]", "algo.params.actor_hold_updates=10", "algo.params.q_ramp_updates=10",
            f"run_dir={tmp_path / 'run'}", "progress=false", "tensorboard=false"]))
    assert cfg.learner_params["filtered_bc"] and cfg.learner_params["probe"] and cfg.learner_params["freeze_normalizer"]
    rows = train(cfg)
    assert [r["epoch"] for r in rows] == [0, 1, 2, 3]
    assert np.isfinite(rows[0]["critic_pretrain_loss"]) and rows[0]["probe_pi_to_bc"] == 0.0
    for row in rows[1:]:  # the filter and the probe are live in every online epoch
        assert 0.0 <= row["advantage_pass"] <= 1.0 and row["probe_pi_to_bc"] > 0.0
    assert json.loads((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()[-1])["epoch"] == 3


def _criteria_of(successes, steps_per_epoch=2000):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from plot_curves import criteria

    return criteria([{"epoch": e, "env_steps": e * steps_per_epoch, "success_rate": s} for e, s in enumerate(successes)])


def test_plot_curves_check_reads_the_issue_criteria():
    baseline = [_criteria_of([0.8, 0.0, 0.0, 0.5, 0.9] + [0.9] * 8)] * 3        # 90 % first at epoch 4: 8k steps
    kept = [_criteria_of([0.6, 0.4, 0.5, 0.7, 0.95] + [0.9] * 8)] * 3           # min 0.4 >= 0.5 x 0.6, 8k steps
    from plot_curves import check  # importable once _criteria_of has put benchmarks/ on the path

    assert check({"ddpgbc": baseline, "warm": kept}) == []
    dropped = [_criteria_of([0.6, 0.2, 0.5, 0.7, 0.95] + [0.9] * 8)] * 3        # 0.2 < 0.3
    assert any("fell to 0.20" in f for f in check({"ddpgbc": baseline, "warm": dropped}))
    slower = [_criteria_of([0.6, 0.4, 0.5, 0.7, 0.8, 0.95] + [0.9] * 7)] * 3    # 10k steps > 8k
    assert any("median steps" in f for f in check({"ddpgbc": baseline, "warm": slower}))
    one_never = kept[:2] + [_criteria_of([0.6] + [0.5] * 12)]                  # median still 8k
    assert check({"ddpgbc": baseline, "warm": one_never}) == []
    assert any("median steps" in f for f in check({"ddpgbc": baseline, "warm": kept[:1] + one_never[2:] * 2}))
    short = [_criteria_of([0.6, 0.5, 0.95])] * 3
    assert any("only 2 online epochs" in f for f in check({"ddpgbc": baseline, "warm": short}))
    never = [_criteria_of([0.8] + [0.5] * 12)] * 3
    assert any("ddpgbc seed 0" in f for f in check({"ddpgbc": never, "warm": kept}))

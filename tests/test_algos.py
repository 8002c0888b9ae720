"""Offline-to-online learning: HER replay, DDPG(+BC) loss pieces, SAC, the run loop, exact resume, Hydra sweeps."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from surrol_data.algos.ddpg import DDPG, DDPGConfig
from surrol_data.algos.demos import DemoSpec, load_demos
from surrol_data.algos.replay import EpisodeReplay, her_ratio_for
from surrol_data.algos.sac import SAC, SACConfig
from surrol_data.algos.train import Schedule, TrainConfig, read_metrics, train

REACH = "SurRoL/NeedleReach-v0"
REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "surrol_data.cli"]


def sparse_reward(ag, g):
    return (np.linalg.norm(np.asarray(ag) - np.asarray(g), axis=-1) < 0.005).astype(np.float32) - 1.0


def coded_episode(ep: int, length: int):
    """Observations and achieved goals that encode (episode, step), so a sample says where it came from."""
    steps = np.arange(length + 1, dtype=np.float32)
    obs = np.stack([np.full(length + 1, ep, np.float32), steps], axis=1)
    ag = np.stack([np.full(length + 1, ep, np.float32), steps, np.zeros(length + 1, np.float32)], axis=1)
    g = np.tile(np.array([[-1.0, -1.0, -1.0]], np.float32), (length, 1))  # the env's goal: never achieved
    action = np.full((length, 1), ep / 100.0, np.float32)
    return obs, ag, g, action


# --- HER replay --------------------------------------------------------------------------------

def test_her_future_relabelling_is_correct_for_episodes_of_any_length():
    buf = EpisodeReplay(8, horizon=10, obs_dim=2, goal_dim=3, act_dim=1, reward_fn=sparse_reward, her_k=4, seed=0)
    lengths = {0: 10, 1: 3, 2: 1, 3: 7}
    for ep, n in lengths.items():
        buf.add_episode(*coded_episode(ep, n))
    b = buf.sample(20000)
    ep, t = b["obs"][:, 0].astype(int), b["obs"][:, 1].astype(int)
    # transitions stay inside their episode: s_{t+1} follows s_t and t < length
    assert np.all(b["next_obs"][:, 1] == t + 1) and np.all(b["next_obs"][:, 0] == ep)
    assert all(np.all(t[ep == e] < n) for e, n in lengths.items())
    np.testing.assert_array_equal(b["action"][:, 0], (ep / 100.0).astype(np.float32))
    relabelled = b["g"][:, 0] >= 0
    assert abs(relabelled.mean() - her_ratio_for(4)) < 0.02 and her_ratio_for(4) == pytest.approx(0.8)
    # a hindsight goal is the achieved goal of a later state t+1 … length of the same episode
    assert np.all(b["g"][relabelled, 0] == ep[relabelled])
    future = b["g"][relabelled, 1].astype(int)
    assert np.all(future >= t[relabelled] + 1)
    assert np.all(future <= np.array([lengths[e] for e in ep[relabelled]]))
    # … uniformly: for t = 0 of the 10-step episode every future index 1..10 shows up about equally often
    picks = future[(ep[relabelled] == 0) & (t[relabelled] == 0)]
    counts = np.bincount(picks, minlength=11)[1:]
    assert counts.min() > 0.5 * counts.mean()
    # rewards are recomputed in one batch: 0 exactly when the next achieved goal is the (hindsight) goal
    np.testing.assert_array_equal(b["reward"], sparse_reward(b["next_ag"], b["g"]))
    assert np.all(b["reward"][b["g"][:, 1] == t + 1] == 0.0) and np.all(b["reward"][~relabelled] == -1.0)


def test_replay_overwrites_random_slots_and_round_trips_its_state():
    buf = EpisodeReplay(4, horizon=5, obs_dim=2, goal_dim=3, act_dim=1, reward_fn=sparse_reward, seed=1)
    for ep in range(12):
        buf.add_episode(*coded_episode(ep, 5))
    assert len(buf) == 4 and buf.episodes_added == 12 and buf.transitions == 20
    kept = set(buf.obs[:, 0, 0].astype(int))
    assert kept != {8, 9, 10, 11} and len(kept) == 4  # not FIFO
    copy = EpisodeReplay(4, horizon=5, obs_dim=2, goal_dim=3, act_dim=1, reward_fn=sparse_reward, seed=99)
    copy.load_state_dict(buf.state_dict())
    a, b = buf.sample(64), copy.sample(64)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    with pytest.raises(ValueError, match="same task"):
        buf.add_episode(np.zeros((6, 4)), np.zeros((6, 3)), np.zeros((5, 3)), np.zeros((5, 1)))
    with pytest.raises(ValueError, match="L\\+1 observations"):
        buf.add_episode(np.zeros((5, 2)), np.zeros((6, 3)), np.zeros((5, 3)), np.zeros((5, 1)))


# --- DDPG(+BC) loss pieces ----------------------------------------------------------------------

def _zero_(module):
    with torch.no_grad():
        for p in module.parameters():
            p.zero_()


def _batch(n=64, seed=0):
    rng = np.random.default_rng(seed)
    return {"o": torch.randn(n, 7), "g": torch.randn(n, 3), "o2": torch.randn(n, 7),
            "a": torch.from_numpy(rng.uniform(-1, 1, (n, 5)).astype(np.float32)),
            "r": torch.full((n,), -1.0)}


def test_ddpg_td_target_is_clamped_to_the_range_of_sparse_returns():
    agent = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,)))
    _zero_(agent.critic_target)  # Q'(s', π'(s')) is its output bias alone
    for bias, expected_target in ((+1000.0, 0.0), (-1000.0, -100.0)):
        with torch.no_grad():
            agent.critic_target.net[-1].bias.fill_(bias)
        _zero_(agent.critic)
        loss, q = agent._critic_step(_batch())
        assert q == 0.0 and loss == pytest.approx(expected_target**2)
    agent.config.clip_target = False
    _zero_(agent.critic)
    loss, _ = agent._critic_step(_batch())
    assert loss == pytest.approx((-1.0 + 0.99 * -1000.0) ** 2, rel=1e-5)


def test_ddpg_bc_term_is_per_dimension_mse_gated_by_the_target_q_filter():
    cfg = DDPGConfig(hidden_sizes=(16,), bc_weight=5.0, action_l2=0.0, q_filter=False, actor_lr=0.0)
    agent = DDPG(7, 3, 5, cfg)
    _zero_(agent.critic)  # Q ≡ 0: the actor loss is the BC term alone
    b = _batch()
    with torch.no_grad():
        pi = agent.actor(b["o"], b["g"])
    out = agent._actor_step([(b, True)])
    assert out["q_filter_pass"] == 1.0 and out["bc_loss"] == pytest.approx(((pi - b["a"]) ** 2).mean().item(), rel=1e-5)
    assert out["actor_loss"] == pytest.approx(5.0 * out["bc_loss"], rel=1e-5)
    # Q-filter on: the BC term applies only where the target critic rates the demo action at least as high
    agent.config.q_filter = True
    agent.critic_target = lambda o, g, a: -(a - pi).pow(2).sum(-1)  # prefers the actor's own action
    assert agent._actor_step([(b, True)])["q_filter_pass"] == 0.0
    agent.critic_target = lambda o, g, a: -(a - b["a"]).pow(2).sum(-1)  # prefers the demo's action
    assert agent._actor_step([(b, True)])["q_filter_pass"] == 1.0


def test_ddpg_update_uses_demo_batches_only_with_a_bc_weight():
    replay = EpisodeReplay(4, 5, 7, 3, 5, sparse_reward, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(3):
        replay.add_episode(rng.normal(size=(6, 7)), rng.normal(size=(6, 3)), rng.normal(size=(5, 3)),
                           rng.uniform(-1, 1, (5, 5)))
    with_bc = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,))).update(replay, replay)
    assert {"critic_loss", "actor_loss", "q", "bc_loss", "q_filter_pass"} <= set(with_bc)
    plain = DDPG(7, 3, 5, DDPGConfig(hidden_sizes=(16,), bc_weight=0.0)).update(replay, replay)
    assert "bc_loss" not in plain


def test_sac_log_prob_matches_a_monte_carlo_density_and_policy_export_is_tanh_mu():
    torch.manual_seed(0)   # the networks' initialisation draws from torch's global generator
    agent = SAC(7, 3, 5, SACConfig(hidden_sizes=(32,)))
    o, g = torch.randn(1, 7).repeat(4000, 1), torch.randn(1, 3).repeat(4000, 1)
    a, logp = agent.actor(o, g, generator=torch.Generator().manual_seed(0))
    assert a.abs().max() < 1 and torch.isfinite(logp).all()
    # change of variables: log π(a) = log N(atanh a) − Σ log(1 − a²)
    mu, raw = agent.actor.net(torch.cat([o, g], -1)).chunk(2, -1)
    log_std = -4 + 3 * (torch.tanh(raw) + 1)
    u = torch.atanh(a.clamp(-1 + 1e-6, 1 - 1e-6))
    ref = torch.distributions.Normal(mu, log_std.exp()).log_prob(u).sum(-1) - torch.log(1 - a.pow(2) + 1e-12).sum(-1)
    # where tanh saturates in float32, atanh(a) no longer recovers the pre-squash sample: compare elsewhere
    inside = a.abs().amax(-1) < 0.999
    assert inside.float().mean() > 0.5
    assert torch.allclose(logp[inside], ref[inside], atol=2e-2)
    policy = agent.policy()
    obs = {"observation": np.random.default_rng(0).normal(size=(8, 7)).astype(np.float32),
           "desired_goal": np.zeros((8, 3), np.float32)}
    np.testing.assert_allclose(policy.act(obs), agent.act(obs, explore=False), atol=1e-6)


# --- demos by provenance ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def reach_demos(tmp_path_factory):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("demos") / "NeedleReach_script"
    collect_script("NeedleReach", 6, root, progress=False)
    return root


def test_demos_are_selected_by_provenance(reach_demos):
    trajs, eps = load_demos(DemoSpec(path=str(reach_demos), where={"source": "script"}, num=4), REACH)
    assert eps == [0, 1, 2, 3] and len(trajs) == 4 and trajs[0].observation.shape[1] == 7
    with pytest.raises(ValueError, match="no episode of .* matches"):
        load_demos(DemoSpec(path=str(reach_demos), where={"skill": "expert"}, num=1), REACH)
    with pytest.raises(ValueError, match="not of SurRoL/NeedlePick-v0"):
        load_demos(DemoSpec(path=str(reach_demos), num=1), "SurRoL/NeedlePick-v0")
    with pytest.raises(FileNotFoundError, match="surrol-data collect --source script"):
        load_demos(DemoSpec(path=str(reach_demos) + "_missing", num=1), REACH)
    assert load_demos(DemoSpec(path=None), REACH) == ([], [])


# --- the run loop -------------------------------------------------------------------------------

def _overrides(run_dir, demos_root, *extra):
    return ["task=NeedleReach", "algo=ddpgbc", "demos=script", "demos.num=4", f"demos_root={demos_root}",
            "experiment=smoke", f"run_dir={run_dir}", "progress=false", "tensorboard=false", *extra]


def _comparable(rows):
    """Rows without their timings, as JSON text (so NaN equals NaN)."""
    return json.dumps([{k: v for k, v in r.items() if k != "wall_s" and not k.startswith("time_")} for r in rows])


def test_train_writes_curves_checkpoints_and_a_loadable_policy(tmp_path, reach_demos):
    from surrol_data.algos.policies import load_policy

    cfg = TrainConfig(env_id=REACH, run_dir=str(tmp_path / "run"), learner="ddpg",
                      learner_params={"hidden_sizes": (32, 32)},
                      demos=DemoSpec(path=str(reach_demos), num=4),
                      schedule=Schedule(epochs=2, cycles=2, episodes_per_cycle=2, updates_per_cycle=3, n_envs=1,
                                        eval_episodes=2, offline_steps=10, buffer_episodes=20),
                      progress=False)
    rows = train(cfg)
    assert [r["epoch"] for r in rows] == [0, 1, 2] and rows[-1]["env_steps"] == 2 * 2 * 2 * 50
    assert rows[-1]["updates"] == 2 * 2 * 3
    for key in ("success_rate", "steps_to_complete", "economy_of_motion_cm", "critic_loss", "bc_loss", "wall_s"):
        assert key in rows[-1]
    assert read_metrics(cfg.run_dir) == json.loads(json.dumps(rows))
    assert (Path(cfg.run_dir) / "metrics.csv").read_text().startswith("epoch,")
    assert (Path(cfg.run_dir) / "tb").is_dir()
    policy = load_policy(Path(cfg.run_dir) / "policy.pt")
    assert policy({"observation": np.zeros(7, np.float32), "desired_goal": np.zeros(3, np.float32)}).shape == (5,)
    # resuming a finished run changes nothing; resuming with another config is refused
    assert _comparable(train(TrainConfig(**{**cfg.__dict__, "resume": True}))) == _comparable(rows)
    other = TrainConfig(**{**cfg.__dict__, "resume": True, "seed": 5})
    with pytest.raises(ValueError, match="another configuration"):
        train(other)
    # a run begun with overwrite=true resumes with resume=true alone (how it was launched is not its config)
    again = TrainConfig(**{**cfg.__dict__, "overwrite": True, "tensorboard": False})
    train(again)
    assert _comparable(train(TrainConfig(**{**again.__dict__, "overwrite": False, "resume": True}))) == \
        _comparable(read_metrics(cfg.run_dir))


@pytest.mark.slow  # three short runs in subprocesses: ~30 s on a quiet 2-core machine
def test_resume_after_kill_continues_the_curve(tmp_path, reach_demos):
    """Kill a run after its second checkpoint, resume it, and get the rows of a run that never stopped."""
    base = _overrides(tmp_path / "killed", reach_demos.parent, "experiment.epochs=6", "experiment.n_envs=2",
                      "experiment.episodes_per_cycle=2", "algo.params.hidden_sizes=[64,64]")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([*CLI, "train", *base], cwd=tmp_path, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    metrics = tmp_path / "killed" / "metrics.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 3:  # epochs 0, 1, 2 done
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"the run ended before it could be killed: {proc.stderr.read().decode()[-2000:]}"
    os.killpg(proc.pid, signal.SIGKILL)  # the run and its env workers, as a crash would
    proc.wait()
    killed_at = len(read_metrics(tmp_path / "killed"))
    assert 3 <= killed_at < 7
    subprocess.run([*CLI, "train", *base, "resume=true"], cwd=tmp_path, env=env, check=True, capture_output=True)
    resumed = read_metrics(tmp_path / "killed")
    straight = _overrides(tmp_path / "straight", reach_demos.parent, "experiment.epochs=6", "experiment.n_envs=2",
                          "experiment.episodes_per_cycle=2", "algo.params.hidden_sizes=[64,64]")
    subprocess.run([*CLI, "train", *straight], cwd=tmp_path, env=env, check=True, capture_output=True)
    assert [r["epoch"] for r in resumed] == list(range(7))
    assert _comparable(resumed) == _comparable(read_metrics(tmp_path / "straight"))
    # it resumed from a checkpoint (not from scratch); a row written after the last checkpoint was replaced
    assert 1 <= json.loads((tmp_path / "killed" / "process.json").read_text())["resumed_after_epoch"] <= killed_at - 1


@pytest.mark.slow  # Hydra + two joblib worker processes: ~20 s
def test_two_job_local_sweep_runs_in_parallel_processes(tmp_path, reach_demos):
    overrides = _overrides("sweep/seed${seed}", reach_demos.parent, "experiment.epochs=2", "hydra.sweep.dir=multirun",
                           "algo.params.hidden_sizes=[32,32]")
    result = subprocess.run([*CLI, "train", "-m", "seed=0,1", *overrides], cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    procs = [json.loads((tmp_path / "sweep" / f"seed{s}" / "process.json").read_text()) for s in (0, 1)]
    assert procs[0]["pid"] != procs[1]["pid"] and os.getpid() not in {p["pid"] for p in procs}
    # the two jobs overlapped in time: each started before the other finished
    assert procs[0]["started"] < procs[1]["finished"] and procs[1]["started"] < procs[0]["finished"]
    assert all(p["epochs_done"] == 2 for p in procs)
    assert len(read_metrics(tmp_path / "sweep" / "seed1")) == 3


@pytest.mark.slow  # ~1 min each: both reached 100 % at epoch 5 (5k env steps) in the measured runs
@pytest.mark.parametrize("learner, params, warmup", [
    ("ddpg", {"bc_weight": 0.0}, 1000),                                              # DDPG+HER
    ("sac", {"actor_lr": 3e-4, "critic_lr": 3e-4, "alpha_lr": 3e-4, "clip_target": True}, 1000),  # SAC+HER
])
def test_her_learners_learn_needle_reach_without_demos(tmp_path, learner, params, warmup):
    cfg = TrainConfig(env_id=REACH, run_dir=str(tmp_path / "reach"), learner=learner, learner_params=params,
                      schedule=Schedule(epochs=8, cycles=10, updates_per_cycle=40, eval_episodes=20,
                                        warmup_steps=warmup, n_envs=2),
                      progress=False)
    rows = train(cfg)
    assert max(r["success_rate"] for r in rows) >= 0.9, [r["success_rate"] for r in rows]


def test_hydra_configs_compose_into_train_configs(tmp_path, monkeypatch):
    from hydra import compose, initialize_config_dir

    from surrol_data.train_app import config_dir, to_train_config

    assert config_dir() == REPO / "configs"
    monkeypatch.chdir(tmp_path)
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        expert = to_train_config(compose("config", ["demos=expert", "demos.num=40", "seed=3"]))
        assert expert.learner == "ddpg" and expert.learner_params["bc_weight"] == 5.0
        assert expert.demos.where == {"source": "haptic", "skill": "expert"} and expert.demos.num == 40
        assert expert.demos.path == str(tmp_path / "datasets" / "NeedlePick_human")
        assert expert.run_dir == str(tmp_path / "runs" / "NeedlePick" / "ddpgbc" / "expert" / "seed3")
        assert expert.schedule.offline_steps == 2000 and expert.schedule.online
        paper = to_train_config(compose("config", ["experiment=paper", "algo=sac_her", "demos=none",
                                                   "task=NeedleReach"]))
        assert paper.schedule.max_episode_steps == 150 and paper.schedule.episodes_per_cycle * paper.schedule.cycles == 40
        assert paper.learner == "sac" and paper.schedule.her_k == 4 and paper.demos.path is None
        warm = to_train_config(compose("config", ["algo=ddpgbc_warm"]))
        assert warm.learner_params["filtered_bc"] and warm.learner_params["critic_pretrain_steps"] > 0
        assert warm.run_dir.endswith("ddpgbc_warm/script/seed0")
        # the paper-faithful default has none of the warm start
        assert not {"filtered_bc", "freeze_normalizer", "critic_pretrain_steps", "actor_hold_updates"} & set(expert.learner_params)
        reference = to_train_config(compose("config", ["experiment=reference", "algo=bc"]))
        assert reference.schedule.max_episode_steps == 50 and not reference.schedule.online

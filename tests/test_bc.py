"""Normaliser, networks, behaviour cloning, and policy rollouts through the real SurRoL envs."""


import gymnasium as gym
import numpy as np
import pytest
import torch

from surrol_data.algos.bc import BCConfig, BCPolicy, demo_arrays, train_bc
from surrol_data.algos.networks import DeterministicActor, mlp
from surrol_data.algos.normalizer import Normalizer
from surrol_data.algos.policies import load_policy
from surrol_data.evaluation.rollout import evaluate, rollout

REACH = "SurRoL/NeedleReach-v0"
PICK = "SurRoL/NeedlePick-v0"


# --- normaliser and networks -------------------------------------------------------------------

def test_normalizer_matches_numpy_statistics_when_fed_in_chunks():
    x = np.random.default_rng(0).normal([1.0, -2.0, 0.5], [0.3, 2.0, 0.001], size=(1000, 3))
    norm = Normalizer(3)
    for chunk in np.array_split(x, 7):
        norm.update(chunk)
    assert norm.count == 1000
    np.testing.assert_allclose(norm.mean, x.mean(axis=0), rtol=1e-10)
    # The third feature varies by 1e-3 < eps = 0.01, so its std is floored at eps.
    np.testing.assert_allclose(norm.std, [x[:, 0].std(), x[:, 1].std(), 0.01], rtol=1e-8)
    z = norm.normalize(x)
    assert z.dtype == np.float32 and z.shape == x.shape
    np.testing.assert_allclose(z[:, :2].mean(axis=0), 0.0, atol=1e-5)
    assert norm.normalize(np.array([1e6, 0.0, 0.0]))[0] == 5.0  # clipped


def test_normalizer_state_round_trip_and_errors():
    norm = Normalizer(2)
    norm.update(np.array([[1.0, 2.0], [3.0, 5.0]]))
    copy = Normalizer.from_state_dict(norm.state_dict())
    np.testing.assert_array_equal(copy.mean, norm.mean)
    np.testing.assert_array_equal(copy.std, norm.std)
    assert copy.count == 2
    with pytest.raises(ValueError, match="last dimension of 2"):
        norm.update(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        norm.update(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="size 2 into one of size 3"):
        Normalizer(3).load_state_dict(norm.state_dict())


def test_mlp_and_actor_shapes():
    net = mlp(10, 4)
    assert [m.out_features for m in net if isinstance(m, torch.nn.Linear)] == [256, 256, 256, 4]
    assert [m.out_features for m in mlp(3, 2, hidden_sizes=(8,)) if isinstance(m, torch.nn.Linear)] == [8, 2]
    actor = DeterministicActor(7, 3, 5, hidden_sizes=(32, 32))
    a = actor(100 * torch.randn(64, 7), 100 * torch.randn(64, 3))
    assert a.shape == (64, 5) and a.abs().max() <= 1.0


# --- behaviour cloning on synthetic data ------------------------------------------------------

def linear_demos(n: int = 2000, seed: int = 0):
    """Actions that are a fixed linear map of (obs, goal), inside (-1, 1). Obs are in metres-like scales."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(0.0, 0.02, (n, 7)).astype(np.float32) + np.float32(0.7)
    goal = rng.normal(0.0, 0.02, (n, 3)).astype(np.float32) + np.float32(0.7)
    w = np.random.default_rng(123).uniform(-0.2, 0.2, (10, 5))
    z = (np.concatenate([obs, goal], axis=1) - 0.7) / 0.02  # the map is simple in normalised units
    action = np.clip(z @ w, -0.95, 0.95).astype(np.float32)
    return obs, goal, action, np.repeat(np.arange(n // 50), 50)


SMALL = BCConfig(hidden_sizes=(64, 64), epochs=10, steps_per_epoch=100)


def test_bc_fits_a_linear_mapping():
    obs, goal, action, episode = linear_demos()
    policy = train_bc(obs, goal, action, BCConfig(), episode_index=episode, progress=False)
    assert len(policy.log) == 20 and policy.log[-1]["step"] == 2000
    assert policy.log[-1]["train_loss"] < 0.1 * policy.log[0]["train_loss"]
    assert policy.log[-1]["val_loss"] < 2e-3
    # Fresh data from the same map.
    o2, g2, a2, _ = linear_demos(500, seed=1)
    pred = policy.act({"observation": o2, "desired_goal": g2})
    assert pred.shape == (500, 5) and pred.dtype == np.float32
    assert np.mean((pred - a2) ** 2) < 2e-3


def test_bc_is_deterministic_given_a_seed():
    obs, goal, action, episode = linear_demos(500)
    p1, p2 = (train_bc(obs, goal, action, SMALL, episode_index=episode, progress=False) for _ in range(2))
    for t1, t2 in zip(p1.actor.state_dict().values(), p2.actor.state_dict().values()):
        assert torch.equal(t1, t2)
    assert p1.log == p2.log
    p3 = train_bc(obs, goal, action, BCConfig(**{**SMALL.__dict__, "seed": 1}), episode_index=episode, progress=False)
    assert not torch.equal(p1.actor.net[0].weight, p3.actor.net[0].weight)


def test_bc_holds_out_whole_episodes():
    obs, goal, action, episode = linear_demos(1000)  # 20 episodes → 2 held out
    policy = train_bc(obs, goal, action, SMALL, episode_index=episode, progress=False)
    assert policy.obs_norm.count == 900
    no_val = train_bc(obs, goal, action, BCConfig(**{**SMALL.__dict__, "val_fraction": 0.0}), progress=False)
    assert no_val.obs_norm.count == 1000 and np.isnan(no_val.log[-1]["val_loss"])


def test_bc_save_load_round_trip(tmp_path):
    obs, goal, action, episode = linear_demos(500)
    policy = train_bc(obs, goal, action, SMALL, episode_index=episode, progress=False)
    path = policy.save(tmp_path / "sub" / "bc.pt")
    loaded = BCPolicy.load(path)
    batch = {"observation": obs[:32], "desired_goal": goal[:32]}
    np.testing.assert_array_equal(loaded.act(batch), policy.act(batch))
    single = {"observation": obs[0], "desired_goal": goal[0], "achieved_goal": goal[0]}
    assert loaded(single).shape == (5,)
    np.testing.assert_array_equal(loaded(single), policy(single))
    assert loaded.config == policy.config and loaded.log == policy.log
    assert isinstance(load_policy(path), BCPolicy)


def test_bc_errors_are_explicit(tmp_path):
    obs, goal, action, episode = linear_demos(500)
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        train_bc(obs, goal, 3 * action, SMALL, progress=False)
    with pytest.raises(ValueError, match="same number of rows"):
        train_bc(obs, goal[:10], action, SMALL, progress=False)
    policy = train_bc(obs, goal, action, SMALL, episode_index=episode, progress=False)
    with pytest.raises(ValueError, match="observation dim 7"):
        policy.act({"observation": np.zeros(19), "desired_goal": np.zeros(3)})
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a BC checkpoint"):
        BCPolicy.load(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError, match="neither 'oracle'"):
        load_policy(tmp_path / "missing.pt")


def hesitant_demos(n: int = 2000, seed: int = 0):
    """A person at the grasp pose: from the same state the jaw command is "hold open" (+0.8) 70 % of the time
    and "close" (−0.8) 30 %; the other channels follow the state linearly."""
    obs, goal, action, episode = linear_demos(n, seed)
    closing = np.random.default_rng(seed + 1).random(n) < 0.3
    action[:, -1] = np.where(closing, -0.8, 0.8)
    return obs, goal, action, episode


def test_bc_gmm_keeps_a_hesitation_that_an_mse_actor_averages_away():
    obs, goal, action, episode = hesitant_demos()
    gmm_config = BCConfig(**{**SMALL.__dict__, "epochs": 20, "gmm_modes": 5})
    gmm = train_bc(obs, goal, action, gmm_config, episode_index=episode, progress=False)
    mse = train_bc(obs, goal, action, SMALL, episode_index=episode, progress=False)
    new_obs, new_goal, new_action, _ = hesitant_demos(1000, seed=7)    # states neither policy saw
    batch = {"observation": new_obs, "desired_goal": new_goal}
    jaw_mse, jaw_gmm = mse.act(batch)[:, -1], gmm.act(batch)[:, -1]
    # The MSE actor answers around the average (+0.32): a compromise no person gave, too weak to close the jaw
    # when it happens to dip below zero. BC-GMM gives the person's commands, closing about as often as they did.
    assert abs(jaw_mse.mean() - 0.32) < 0.1 and np.abs(np.abs(jaw_mse) - 0.8).mean() > 0.3
    assert 0.2 < (jaw_gmm < 0).mean() < 0.4
    assert np.abs(np.abs(jaw_gmm) - 0.8).mean() < 0.05
    # The state-driven channels are still learned (the negative log-likelihood fell by the epochs).
    assert gmm.log[-1]["train_loss"] < gmm.log[0]["train_loss"]
    assert np.abs(gmm.act(batch)[:, :-1] - new_action[:, :-1]).mean() < 0.1


def test_bc_gmm_round_trips_and_acts_the_same_for_its_seed(tmp_path):
    obs, goal, action, episode = hesitant_demos(500)
    policy = train_bc(obs, goal, action, BCConfig(**{**SMALL.__dict__, "gmm_modes": 3}), episode_index=episode,
                      progress=False)
    path = policy.save(tmp_path / "gmm.pt")
    batch = {"observation": obs[:64], "desired_goal": goal[:64]}
    first, again = BCPolicy.load(path), BCPolicy.load(path)
    assert first.config.gmm_modes == 3
    drawn = [first.act(batch) for _ in range(3)]
    np.testing.assert_array_equal(np.stack(drawn), np.stack([again.act(batch) for _ in range(3)]))
    assert not np.array_equal(drawn[0], drawn[1])   # a fresh mode per call, not one fixed choice
    torch.manual_seed(0)
    before = torch.rand(1)
    torch.manual_seed(0)
    first.act(batch)
    assert torch.rand(1) == before                  # acting leaves the global torch seed alone
    with pytest.raises(ValueError, match="gmm_modes >= 0"):
        train_bc(obs, goal, action, BCConfig(**{**SMALL.__dict__, "gmm_modes": -1}), progress=False)


# --- rollouts and evaluation in the real envs --------------------------------------------------

@pytest.fixture(scope="module")
def reach_env():
    import surrol_data.envs  # noqa: F401  (registers the ids)

    env = gym.make(REACH)
    yield env
    env.close()


def test_rollout_runs_the_full_horizon_and_is_reproducible(reach_env):
    traj = rollout(reach_env, "oracle", seed=3)
    assert len(traj) == 50  # keeps going after success
    assert traj.observation.shape == (51, 7) and traj.action.shape == (50, 5)
    assert traj.tip_position.shape == (51, 1, 3) and traj.jaw_angle.shape == (51, 1)
    assert traj.is_success
    np.testing.assert_array_equal(traj.reward, traj.success.astype(np.float32) - 1)
    again = rollout(reach_env, "oracle", seed=3)
    np.testing.assert_array_equal(traj.observation, again.observation)
    assert len(rollout(reach_env, "oracle", seed=3, max_steps=10)) == 10


def test_rollout_rejects_bad_policies(reach_env):
    with pytest.raises(ValueError, match="action of shape"):
        rollout(reach_env, lambda obs: np.zeros(4), seed=0)
    with pytest.raises(ValueError, match="unknown policy string"):
        rollout(reach_env, "random", seed=0)


def test_evaluate_takes_a_policy_and_load_policy_reads_the_spec(tmp_path):
    # evaluation never imports the learners: a checkpoint path is loaded by algos.policies.load_policy first
    with pytest.raises(ValueError, match="load_policy"):
        evaluate(REACH, str(tmp_path / "bc.pt"), episodes=1, progress=False)
    assert load_policy("oracle") == "oracle"


def test_oracle_evaluates_near_perfectly_on_needle_reach():
    result = evaluate(REACH, "oracle", episodes=20, seed=0, progress=False)
    assert result.seeds == list(range(20)) and len(result.proficiency) == 20
    assert result.summary["success_rate"] >= 0.95
    assert result.trajectories == []


def test_evaluate_overrides_the_horizon_and_keeps_trajectories():
    result = evaluate(REACH, "oracle", episodes=2, seed=5, max_steps=60, progress=False, keep_trajectories=True)
    assert [len(t) for t in result.trajectories] == [60, 60]
    assert [p.steps for p in result.proficiency] == [60, 60]


def test_oracle_evaluates_near_perfectly_on_needle_pick():
    result = evaluate(PICK, "oracle", episodes=20, seed=0, progress=False)
    assert result.summary["success_rate"] >= 0.95


@pytest.mark.slow
@pytest.mark.parametrize("env_id", [REACH, PICK])
def test_oracle_success_over_100_episodes(env_id):
    assert evaluate(env_id, "oracle", episodes=100, seed=0, progress=False).summary["success_rate"] >= 0.95


def test_bc_on_oracle_demos_solves_needle_reach(reach_env, tmp_path):
    demos = [rollout(reach_env, "oracle", seed=s) for s in range(20)]
    obs, goal, action, episode = demo_arrays(demos)
    policy = train_bc(obs, goal, action, BCConfig(), episode_index=episode, progress=False)
    path = policy.save(tmp_path / "bc_reach.pt")
    # Unseen seeds, and through a checkpoint path, as the CLI would do it.
    result = evaluate(REACH, load_policy(str(path)), episodes=20, seed=1000, progress=False)
    assert result.summary["success_rate"] >= 0.7, result.summary

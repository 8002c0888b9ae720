"""The simulated human operator: a device whose frames go through the real mapping into the real env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.devices.base import BUTTON_CLUTCH, DeviceError, DeviceFrame
from surrol_data.collect.mapping import ActionMapper, MappingSettings, view_to_action
from surrol_data.collect.operator import PROFILES, SimulatedOperator, operator_params
from surrol_data.collect.operator.motor import Hand, MotorNoise, fitts_duration, minimum_jerk
from surrol_data.collect.operator.operator import DEVICE_HALF_RANGE, episode_key
from surrol_data.datasets.metrics import Proficiency, trajectory_proficiency
from surrol_data.datasets.trajectory import Trajectory, TrajectoryBuilder
from surrol_data.evaluation.rollout import ORACLE, rollout

HORIZON = 150   # the paper's human recordings are 150 steps (30 s)


@pytest.fixture(scope="module")
def pick_env():
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=HORIZON)
    yield env
    env.close()


def run_episode(env, operator: SimulatedOperator, seed: int, horizon: int = HORIZON,
                stop_on_success: bool = False) -> tuple[Trajectory, list[DeviceFrame]]:
    """The haptic session's per-step loop: observe, read, map, step; recorded like every device."""
    mapper = ActionMapper(operator.mapping)
    obs, info = env.reset(seed=seed)
    builder = TrajectoryBuilder(obs, info["tip_position"], info["jaw_angle"])
    frames = []
    for _ in range(horizon):
        operator.observe(obs, info)
        frame = operator.read()
        step = mapper(frame, view_to_action(env))
        frames.append(frame)
        obs, reward, terminated, truncated, info = env.step(step.arm)
        builder.add(step.arm, obs, reward, info["is_success"], terminated, info["tip_position"], info["jaw_angle"],
                    flags={"clutch": step.clutch, "jaw_button": step.jaw_button})
        if terminated or truncated or (stop_on_success and info["is_success"]):
            break
    return builder.build(), frames


def make_operator(env, skill: str, operator_id: str, seed: int = 0, **overrides) -> SimulatedOperator:
    op = SimulatedOperator(env.unwrapped, skill, operator_id, MappingSettings(), seed, overrides=overrides or None)
    op.connect()
    return op


def profile_runs(env, skill: str, operators: int, episodes: int, first_seed: int, horizon: int = HORIZON):
    scores: list[Proficiency] = []
    events = []
    for i in range(operators):
        op = make_operator(env, skill, f"{skill}-{i}")
        for k in range(episodes):
            traj, _ = run_episode(env, op, first_seed + i * episodes + k, horizon)
            scores.append(trajectory_proficiency(traj))
            events.append([e for _, e in op.events])
    return scores, events


# ---------------------------------------------------------------------------------------------- model parts
def test_profiles_and_identities():
    assert set(PROFILES) == {"expert", "novice"}
    expert, novice = PROFILES["expert"], PROFILES["novice"]
    assert expert.reaction_time_s < novice.reaction_time_s
    assert expert.tremor_mm < novice.tremor_mm and expert.depth_noise_mm < novice.depth_noise_mm
    assert expert.anticipates_clutch and not novice.anticipates_clutch
    # An identity is stable, and identities of one profile differ.
    assert operator_params("novice", "ann") == operator_params("novice", "ann")
    assert operator_params("novice", "ann") != operator_params("novice", "bob")
    assert 8.0 <= operator_params("novice", "ann").tremor_hz <= 12.0
    assert operator_params("expert", "x", {"depth_bias_mm": 3.0}).depth_bias_mm == 3.0
    with pytest.raises(ValueError, match="unknown operator skill"):
        operator_params("surgeon", "ann")
    with pytest.raises(ValueError, match="unknown operator parameter"):
        operator_params("expert", "ann", {"speed": 1.0})


def test_motor_model():
    # Minimum jerk: from 0 to 1, symmetric about the midpoint; Fitts: harder targets take longer.
    assert minimum_jerk(0.0) == 0.0 and minimum_jerk(1.0) == 1.0
    assert minimum_jerk(0.3) + minimum_jerk(0.7) == pytest.approx(1.0)
    assert fitts_duration(40.0, 1.0, 0.2, 0.1) > fitts_duration(40.0, 4.0, 0.2, 0.1) > fitts_duration(5.0, 4.0, 0.2, 0.1)
    # Tremor of a still hand: its power sits in the 8–12 Hz band.
    noise = MotorNoise(endpoint_sd=0.1, drift_sd=0.05, tremor_mm=0.2, tremor_hz=10.0, tremor_gimbal_rad=0.0)
    hand = Hand(np.zeros(4), DEVICE_HALF_RANGE, noise, np.random.default_rng(0))
    t = np.arange(2000) / 1000.0
    x = np.array([hand.sample(s)[0] for s in t])
    spectrum = np.abs(np.fft.rfft(x - x.mean()))
    freqs = np.fft.rfftfreq(len(x), 1e-3)
    assert 8.0 <= freqs[np.argmax(spectrum)] <= 12.0
    assert 0.05 < np.std(x) < 0.5
    # Signal-dependent noise: endpoints of long moves scatter more than those of short ones.
    def scatter(amplitude):
        ends = []
        for seed in range(40):
            h = Hand(np.zeros(4), DEVICE_HALF_RANGE, noise, np.random.default_rng(seed))
            h.move(0.0, np.array([amplitude, 0.0, 0.0, 0.0]), 1.0)
            ends.append(h.planned_pose()[0])
        return np.std(ends)
    assert scatter(60.0) > 3 * scatter(6.0)
    with pytest.raises(ValueError, match="forward in time"):
        hand.sample(0.5)


# ---------------------------------------------------------------------------------------------- device contract
def test_device_contract_and_bad_input(pick_env):
    env = pick_env.unwrapped
    op = SimulatedOperator(env, "expert", "ann", MappingSettings(), seed=0)
    assert op.name == "simulated-operator"
    settings = op.settings()
    assert settings["skill"] == "expert" and settings["params"]["reaction_time_s"] > 0
    import json
    json.dumps(settings)   # provenance needs JSON
    with pytest.raises(DeviceError, match="not connected"):
        op.read()
    op.connect()
    with pytest.raises(DeviceError, match="observe"):
        op.read()
    with pytest.raises(ValueError, match="arm=1"):
        SimulatedOperator(env, "expert", "ann", MappingSettings(), seed=0, arm=1)
    with pytest.raises(ValueError, match="unknown operator skill"):
        SimulatedOperator(env, "master", "ann", MappingSettings(), seed=0)
    with pytest.raises(ValueError, match="seed"):
        SimulatedOperator(env, "expert", "ann", MappingSettings(), seed=-1)
    cartpole = gym.make("CartPole-v1")
    with pytest.raises(ValueError, match="drives PSM, bimanual and ECM tasks"):
        SimulatedOperator(cartpole.unwrapped, "expert", "ann", MappingSettings(), seed=0)
    cartpole.close()


def test_same_operator_same_episode_same_frames(pick_env):
    rows = []
    for _ in range(2):
        op = make_operator(pick_env, "novice", "ann", seed=7)
        _, frames = run_episode(pick_env, op, seed=3, horizon=60)
        rows.append(np.array([f.to_row() for f in frames]))
    np.testing.assert_array_equal(rows[0], rows[1])
    # The episode does not depend on what the operator did before (its device clock has moved on).
    op = make_operator(pick_env, "novice", "ann", seed=7)
    run_episode(pick_env, op, seed=11, horizon=20)
    _, frames = run_episode(pick_env, op, seed=3, horizon=60)
    later = np.array([f.to_row() for f in frames])
    np.testing.assert_array_equal(later[:, :7], rows[0][:, :7])
    assert later[0, 7] > rows[0][0, 7]    # (the timestamps go on)
    # Another seed or another person moves differently.
    other = make_operator(pick_env, "novice", "ann", seed=8)
    _, frames = run_episode(pick_env, other, seed=3, horizon=60)
    assert not np.array_equal(np.array([f.to_row() for f in frames]), rows[0])


def test_episode_key_is_the_reset_not_the_physics(monkeypatch):
    """The operator's noise for an episode is keyed by the task's random generator as the reset left it, not by the
    observation: an arm built with another base yaw (the same scene, the physics different in its last digits, and
    NeedleRings' first observation, settled with the needle in hand, 2e-5 apart) gives the same person-episode;
    another seed, or an unseeded reset, another."""
    from surrol_data.envs import bimanual_env

    def first(yaw1, yaw2, seed):
        monkeypatch.setattr(bimanual_env, "PSM1_BASE_YAW_RAD", yaw1)
        monkeypatch.setattr(bimanual_env, "PSM2_BASE_YAW_RAD", yaw2)
        env = gym.make("SurRoL/NeedleRings-v0")
        try:
            obs, _ = env.reset(seed=seed)
            key = episode_key(env.unwrapped)
            env.reset()
            return obs["observation"], key, episode_key(env.unwrapped)
        finally:
            env.close()

    obs_a, key_a, next_a = first(0.0, 0.0, 3)
    obs_b, key_b, _ = first(np.deg2rad(-110.0), np.deg2rad(-70.0), 3)
    assert np.abs(obs_a - obs_b).max() > 1e-6 and key_a == key_b
    assert next_a != key_a and first(0.0, 0.0, 4)[1] != key_a


def test_two_hands_of_one_person_draw_their_own_noise():
    env = gym.make("SurRoL/NeedleRegrasp-v0")
    try:
        ops = [SimulatedOperator(env.unwrapped, "novice", "n", MappingSettings(), 0, arm=arm) for arm in (0, 1)]
        obs, info = env.reset(seed=0)
        for op in ops:
            op.connect()
            op.observe(obs, info)
        assert ops[0]._rng.random() != ops[1]._rng.random()
    finally:
        env.close()


def test_reach_task_without_a_plan():
    env = gym.make("SurRoL/NeedleReach-v0", max_episode_steps=100)
    try:
        for skill in ("expert", "novice"):
            traj, _ = run_episode(env, make_operator(env, skill, "ann"), seed=0, horizon=100)
            assert traj.is_success, skill
    finally:
        env.close()


# ---------------------------------------------------------------------------------------------- behaviour
def test_recovers_after_a_failed_grasp(pick_env):
    # A person who judges the needle 3 mm higher than it is closes the jaw above the wire; the failure
    # teaches them (depth_learning=0 removes the misjudgement) and they grasp again.
    op = make_operator(pick_env, "expert", "forced-miss", depth_bias_mm=3.0, depth_learning=0.0)
    traj, _ = run_episode(pick_env, op, seed=1)
    events = [e for _, e in op.events]
    assert events.count("close") >= 2 and "grasp-failed" in events, events
    assert events.index("grasp-failed") < len(events) - 1 - events[::-1].index("close")
    assert traj.is_success
    # The recorded data show it: two jaw closures with a re-opening in between, a lift after the second.
    score = trajectory_proficiency(traj)
    assert score.jaw_closures >= 2
    jaw = traj.action[:, 4]
    first_close = int(np.argmax(jaw < 0))
    reopened = first_close + int(np.argmax(jaw[first_close:] >= 0))
    assert reopened > first_close and np.any(jaw[reopened:] < 0)
    assert traj.achieved_goal[-1, 2] > traj.achieved_goal[0, 2] + 0.02   # the needle was lifted in the end


def test_clutch_at_the_workspace_edge(pick_env):
    op = make_operator(pick_env, "novice", "ann")
    traj, frames = run_episode(pick_env, op, seed=2)
    clutched = traj.flags["clutch"]
    onsets = np.flatnonzero(clutched & ~np.concatenate([[False], clutched[:-1]]))
    assert len(onsets) >= 1 and trajectory_proficiency(traj).clutch_uses == len(onsets)
    position = np.array([f.position_mm for f in frames])
    for k in onsets:
        # A novice clutches when the hand is at (or nearly at) the edge of the stylus workspace ...
        assert np.max(np.abs(position[k]) / DEVICE_HALF_RANGE[:3]) > 0.8, position[k]
        # ... and brings that axis back nearer the centre, with the clutch released. (Another axis may still be
        # finishing the move that was under way, so only the axis at the edge is checked.)
        release = k + int(np.argmax(~clutched[k:]))
        edge = int(np.argmax(np.abs(position[k]) / DEVICE_HALF_RANGE[:3]))
        assert abs(position[release, edge]) < abs(position[k, edge]), (position[k], position[release])
    # Clutched frames move nothing; their buttons carry BUTTON_CLUTCH.
    assert np.all(traj.action[clutched, :4] == 0)
    assert all(frames[k].buttons & BUTTON_CLUTCH for k in np.flatnonzero(clutched))


def _compare_profiles(env, operators: int, episodes: int, horizon: int = HORIZON):
    oracle = [trajectory_proficiency(rollout(env, ORACLE, s)) for s in range(1000, 1000 + operators * episodes)]
    expert, expert_events = profile_runs(env, "expert", operators, episodes, 1000, horizon)
    novice, novice_events = profile_runs(env, "novice", operators, episodes, 1000, horizon)

    def ok(scores, field):
        return np.array([getattr(s, field) for s in scores if s.success], np.float64)

    return oracle, expert, novice, expert_events + novice_events, ok


def test_expert_and_novice_differ_on_needle_pick(pick_env):
    oracle, expert, novice, _, ok = _compare_profiles(pick_env, operators=1, episodes=3)
    # The novice errs as people do (hurried grasps, a misjudged depth, lapses of the grip; ~0.7 failed grasps an attempt
    # at its own pace): 3 episodes of 150 steps cannot pin its success rate, which the slow test below and
    # benchmarks/operator_profiles.py (95 of 100 in 300 steps) measure. Here it must succeed at all, to be compared.
    assert sum(s.success for s in expert) == 3 and sum(s.success for s in novice) >= 1
    assert ok(expert, "steps_to_success").mean() < ok(novice, "steps_to_success").mean()
    assert ok(expert, "log_dimensionless_jerk").mean() > ok(novice, "log_dimensionless_jerk").mean()
    assert ok(oracle, "steps_to_success").mean() < ok(expert, "steps_to_success").mean()


@pytest.mark.slow
def test_expert_and_novice_targets_30_attempts():
    """Given the time to finish (300 steps, as benchmarks/operator_profiles.py gives them: 99 and 95 of 100 there),
    both finish nearly every attempt; at the paper's 150 steps a novice who errs as people do finishes about two in
    three (the rest run out of time after a failed grasp or a drop)."""
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=300)
    oracle, expert, novice, events, ok = _compare_profiles(env, operators=3, episodes=10, horizon=300)
    env.close()
    assert np.mean([s.success for s in expert]) >= 0.9
    assert np.mean([s.success for s in novice]) >= 0.85
    for field in ("steps_to_success", "path_length_cm"):
        assert ok(expert, field).mean() < ok(novice, field).mean(), field
        for human in (expert, novice):
            assert ok(human, field).mean() > ok(oracle, field).mean(), field
            assert ok(human, field).std() > ok(oracle, field).std(), field
    assert ok(expert, "log_dimensionless_jerk").mean() > ok(novice, "log_dimensionless_jerk").mean()
    assert any("grasp-failed" in e for e in events)
    assert sum(s.clutch_uses for s in novice) > 0 and sum(s.clutch_uses for s in expert) > 0

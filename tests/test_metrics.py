"""Proficiency metrics on hand-made trajectories whose answers are known in advance."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from surrol_data.datasets.metrics import log_dimensionless_jerk, path_length_m, summarize, trajectory_proficiency
from surrol_data.datasets.trajectory import Trajectory
from surrol_data.envs.units import CONTROL_PERIOD_S


def make_traj(tip: np.ndarray, success=None, jaw=None) -> Trajectory:
    """A trajectory with tip positions (T+1, 3) or (T+1, n_arms, 3) metres; everything else filler."""
    tip = np.asarray(tip, np.float32)
    if tip.ndim == 2:
        tip = tip[:, None, :]
    n, n_arms = len(tip) - 1, tip.shape[1]
    action = np.zeros((n, 5 * n_arms), np.float32)
    action[:, 4::5] = 1.0  # jaw open unless told otherwise
    if jaw is not None:
        action[:, 4] = jaw
    success = np.zeros(n, bool) if success is None else np.asarray(success, bool)
    return Trajectory(
        observation=np.zeros((n + 1, 7), np.float32), achieved_goal=np.zeros((n + 1, 3), np.float32),
        desired_goal=np.zeros((n + 1, 3), np.float32), action=action, reward=success.astype(np.float32) - 1,
        success=success, terminated=np.zeros(n, bool), tip_position=tip, jaw_angle=np.zeros((n + 1, n_arms), np.float32),
    )


def straight_line(steps: int, step_m: float = 0.01) -> np.ndarray:
    return np.stack([np.arange(steps + 1) * step_m, np.zeros(steps + 1), np.full(steps + 1, 0.7)], axis=1)


def minimum_jerk(steps: int, distance_m: float) -> np.ndarray:
    s = np.linspace(0.0, 1.0, steps + 1)
    x = distance_m * (10 * s**3 - 15 * s**4 + 6 * s**5)
    return np.stack([x, 0.5 * x, np.full_like(x, 0.7)], axis=1)


def test_straight_line_path_length_without_success():
    p = trajectory_proficiency(make_traj(straight_line(10)))  # 10 steps of 1 cm
    assert p.steps == 10
    assert p.path_length_full_cm == pytest.approx(10.0, rel=1e-5)
    assert p.path_length_cm == pytest.approx(10.0, rel=1e-5)  # never succeeded: whole episode counts
    assert p.steps_to_success == -1 and math.isnan(p.time_to_success_s)
    assert not p.success and not p.final_success


def test_steps_to_success_and_path_up_to_success():
    success = np.zeros(10, bool)
    success[3:6] = True  # succeeds after the 4th action, loses it after the 6th
    p = trajectory_proficiency(make_traj(straight_line(10), success))
    assert p.success and not p.final_success
    assert p.steps_to_success == 4
    assert p.time_to_success_s == pytest.approx(4 * CONTROL_PERIOD_S)
    assert p.path_length_cm == pytest.approx(4.0, rel=1e-5)
    assert p.path_length_full_cm == pytest.approx(10.0, rel=1e-5)


def test_bimanual_path_length_sums_arms():
    left = straight_line(5)
    right = np.zeros_like(left)
    right[:, 1] = np.arange(6) * 0.02  # 2 cm per step along y only
    p = trajectory_proficiency(make_traj(np.stack([left, right], axis=1)))
    assert p.path_length_full_cm == pytest.approx(5.0 + 10.0, rel=1e-5)


@pytest.mark.parametrize("jaw, closures", [
    ([1, 1, 1, 1], 0),
    ([1, -1, -1, 1, -1, 0.5, -0.2], 3),
    ([-1, -1, -1], 1),   # the jaw starts open, so closing at step 1 is a closure
    ([-1, 0, -1, 0], 2),  # 0 counts as open
])
def test_jaw_closures(jaw, closures):
    traj = make_traj(straight_line(len(jaw)), jaw=np.asarray(jaw, np.float32))
    assert trajectory_proficiency(traj).jaw_closures == closures


def test_smooth_path_scores_smoother_than_jittery_path():
    smooth = minimum_jerk(50, 0.05)
    jitter = smooth + np.random.default_rng(0).normal(0, 0.001, smooth.shape)  # 1 mm tremor
    p_smooth = trajectory_proficiency(make_traj(smooth))
    p_jitter = trajectory_proficiency(make_traj(jitter))
    assert p_smooth.log_dimensionless_jerk > p_jitter.log_dimensionless_jerk + 1.0


def test_jerk_is_dimensionless_and_undefined_when_still():
    path = minimum_jerk(40, 0.03)
    assert log_dimensionless_jerk(path) == pytest.approx(log_dimensionless_jerk(3.0 * path + 0.1), rel=1e-6)
    still = np.tile([0.0, 0.0, 0.7], (20, 1))
    assert math.isnan(log_dimensionless_jerk(still))
    assert trajectory_proficiency(make_traj(still)).idle_fraction == 1.0


def test_summarize_averages_completion_over_successful_episodes():
    ok_at_2 = np.array([False, True, True, True])
    ok_at_4 = np.array([False, False, False, True])
    results = [trajectory_proficiency(make_traj(straight_line(4), s)) for s in (ok_at_2, ok_at_4, np.zeros(4, bool))]
    summary = summarize(results)
    assert summary["episodes"] == 3
    assert summary["success_rate"] == pytest.approx(2 / 3)
    assert summary["final_success_rate"] == pytest.approx(2 / 3)
    assert summary["mean_steps_to_success"] == pytest.approx(3.0)
    assert summary["mean_path_length_cm"] == pytest.approx(3.0, rel=1e-5)  # 2 cm and 4 cm
    assert summary["mean_jaw_closures"] == 0.0
    assert math.isnan(summarize([])["success_rate"])


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(2, 30), st.just(3)), elements=st.floats(-0.1, 0.1)),
       arrays(np.float64, (3,), elements=st.floats(-1, 1)))
def test_path_length_is_translation_invariant_and_at_least_the_chord(path, shift):
    length = path_length_m(path)
    assert length == pytest.approx(path_length_m(path + shift), rel=1e-9, abs=1e-12)
    assert length >= np.linalg.norm(path[-1] - path[0]) - 1e-12


# ------------------------------------------------------------------ metrics added for the Table I study
from surrol_data.datasets.metrics import (  # noqa: E402
    DeviceTrace, angular_economy_rad, bootstrap_ci, estimate, idle_time_s, proficiency, sparc)


def test_minimum_jerk_has_the_textbook_smoothness():
    # x(s) = D(10s³ − 15s⁴ + 6s⁵): ∫ jerk² = 720 D²/T⁵, so LDLJ = −ln 720; its SPARC is −1.41.
    t = np.linspace(0.0, 1.0, 1001)
    path = minimum_jerk(1000, 0.1)
    assert log_dimensionless_jerk(path, dt=1e-3) == pytest.approx(-math.log(720), abs=0.02)
    assert sparc(path, dt=1e-3) == pytest.approx(-1.41, abs=0.02)
    tremor = path + 0.0005 * np.sin(2 * np.pi * 10 * t)[:, None]  # 0.5 mm of 10 Hz tremor
    assert sparc(tremor, dt=1e-3) < sparc(path, dt=1e-3) - 0.5


def test_smoothness_comes_from_the_device_trace_when_there_is_one():
    traj = make_traj(straight_line(10))
    t = np.linspace(0.0, 2.0, 2001)
    s = t / 2.0
    x = 100.0 * (10 * s**3 - 15 * s**4 + 6 * s**5)  # millimetres: smoothness is unit-free
    trace = DeviceTrace(np.stack([x, 0 * x, 0 * x], axis=1), t)
    p = trajectory_proficiency(traj, device_trace=trace)
    assert p.smoothness_source == "device"
    assert p.sparc == pytest.approx(-1.41, abs=0.02)
    assert trajectory_proficiency(traj).smoothness_source == "tip"


def test_failed_grasps_and_drops_from_the_grasp_record():
    jaw = np.array([1, -1, -1, 1, -1, -1, -1, -1, 1, 1], np.float32)   # closures at steps 1 and 4
    grasped = np.array([0, 0, 0, 0, 0, 1, 1, 0, 0, 0], bool)           # 1st closure empty; 2nd holds, then loses it
    traj = make_traj(straight_line(10), jaw=jaw)
    traj.flags["grasped"] = grasped
    p = trajectory_proficiency(traj)
    assert p.jaw_closures == 2
    assert p.failed_grasps == 1
    assert p.drops == 1          # lost at step 7 with the jaw still closed
    released = grasped.copy()
    released[7] = True           # held until the jaw opens at step 8: a release, not a drop
    traj.flags["grasped"] = released
    assert trajectory_proficiency(traj).drops == 0


def test_a_drop_after_success_is_not_counted_and_env_drop_events_win():
    jaw = -np.ones(6, np.float32)
    grasped = np.array([1, 1, 1, 0, 0, 0], bool)
    success = np.array([0, 1, 1, 1, 1, 1], bool)
    assert proficiency(straight_line(6), success, jaw, grasped=grasped).drops == 0
    assert proficiency(straight_line(6), np.zeros(6, bool), jaw, grasped=grasped).drops == 1
    assert proficiency(straight_line(6), np.zeros(6, bool), jaw, grasped=grasped,
                       drop=np.array([0, 1, 0, 0, 1, 1], bool)).drops == 2


def test_collision_onsets_and_unrecorded_events_are_nan():
    traj = make_traj(straight_line(8))
    p = trajectory_proficiency(traj)
    assert math.isnan(p.collisions) and math.isnan(p.failed_grasps) and math.isnan(p.drops)
    traj.flags["collision"] = np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)
    assert trajectory_proficiency(traj).collisions == 3


def test_idle_time_counts_only_long_still_stretches():
    steps = np.r_[np.full(5, 0.01), np.zeros(6), np.full(3, 0.01), np.zeros(3), np.full(2, 0.01)]
    x = np.concatenate([[0.0], np.cumsum(steps)])
    path = np.stack([x, 0 * x, 0 * x + 0.7], axis=1)
    # 6 still steps = 1.2 s ≥ 1 s counts; 3 still steps = 0.6 s does not.
    assert idle_time_s(path) == pytest.approx(6 * CONTROL_PERIOD_S)


def test_angular_economy_wraps_and_bimanual_arm_paths():
    yaw = np.array([3.0, -3.0, -2.9])   # +0.283 rad across ±π, then +0.1
    assert angular_economy_rad(yaw[:, None]) == pytest.approx(2 * np.pi - 6.0 + 0.1, abs=1e-9)
    left, right = straight_line(5), straight_line(5, step_m=0.02)
    p = trajectory_proficiency(make_traj(np.stack([left, right], axis=1)))
    assert (p.path_length_arm1_cm, p.path_length_arm2_cm) == pytest.approx((5.0, 10.0), rel=1e-5)
    assert math.isnan(trajectory_proficiency(make_traj(left)).path_length_arm2_cm)


def test_estimates_over_seeds_with_bootstrap_interval():
    e = estimate([0.5, 0.7, 0.9, float("nan")])
    assert (e.n, e.mean, e.std) == (3, pytest.approx(0.7), pytest.approx(0.2))
    assert 0.5 <= e.ci_low <= 0.7 <= e.ci_high <= 0.9
    assert e.format(1, scale=100) == "70.0 ± 20.0"
    assert estimate([]).format() == "–"
    assert bootstrap_ci([1.0, 2.0, 3.0]) == bootstrap_ci([1.0, 2.0, 3.0])   # seeded

"""The metrics validate recomputes for all episodes at once are those of trajectory_proficiency, episode by episode."""

from __future__ import annotations

import numpy as np
import pytest

from surrol_data.datasets.episode_metrics import STORED, recorded_metrics
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.trajectory import Trajectory


def _episode(rng, steps: int, n_arms: int, success_from: int | None) -> Trajectory:
    success = np.zeros(steps, bool)
    if success_from is not None:
        success[success_from:] = True
        success[success_from + 1::3] = False   # success that comes and goes: the first one counts
    return Trajectory(
        observation=rng.standard_normal((steps + 1, 7 * n_arms)).astype(np.float32),
        achieved_goal=rng.standard_normal((steps + 1, 3)).astype(np.float32),
        desired_goal=rng.standard_normal((steps + 1, 3)).astype(np.float32),
        action=rng.uniform(-1, 1, (steps, 5 * n_arms)).astype(np.float32),
        reward=success.astype(np.float32) - 1, success=success, terminated=np.zeros(steps, bool),
        tip_position=(0.01 * rng.standard_normal((steps + 1, n_arms, 3))).astype(np.float32),
        jaw_angle=rng.uniform(0, 1, (steps + 1, n_arms)).astype(np.float32),
        flags={"clutch": rng.random(steps) > 0.6, "jaw_button": rng.random(steps) > 0.5})


@pytest.mark.parametrize("n_arms", [1, 2])
def test_all_episodes_at_once_equal_one_at_a_time(n_arms):
    rng = np.random.default_rng(n_arms)
    episodes = [_episode(rng, steps, n_arms, first) for steps, first in
                [(1, None), (1, 0), (6, 0), (9, 4), (12, None), (5, 4), (30, 17)]]
    cat = lambda f: np.concatenate([f(t) for t in episodes])  # noqa: E731
    got = recorded_metrics(np.array([len(t) for t in episodes]), cat(lambda t: t.success), cat(lambda t: t.action),
                           cat(lambda t: t.tip_position[:-1].reshape(len(t), -1)),
                           cat(lambda t: t.tip_position[1:].reshape(len(t), -1)), cat(lambda t: t.flags["clutch"]),
                           n_arms)
    assert set(got) == set(STORED)
    for i, traj in enumerate(episodes):
        want = trajectory_proficiency(traj)
        assert got["success"][i] == want.success
        assert got["steps_to_success"][i] == want.steps_to_success
        assert got["path_length_cm"][i] == pytest.approx(want.path_length_cm, rel=1e-12, abs=1e-12)
        assert got["jaw_closures"][i] == want.jaw_closures
        assert got["clutch_uses"][i] == want.clutch_uses
        assert got["episode_steps"][i] == want.steps


def test_an_action_without_a_jaw_dimension_has_no_closures():
    got = recorded_metrics(np.array([3]), np.zeros(3, bool), -np.ones((3, 3)), np.zeros((3, 3)), np.ones((3, 3)),
                           None, 1)
    assert got["jaw_closures"].tolist() == [0] and got["clutch_uses"].tolist() == [0]
    assert got["path_length_cm"][0] == pytest.approx(100 * np.sqrt(3))   # only the last step moves

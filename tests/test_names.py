"""Every registered task names each dimension of its observation, goals and action, and the arms it moves."""

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.script_source import features_for
from surrol_data.envs import TASKS, env_id
from surrol_data.envs.names import dimension_names

ROBOT_TYPES = {"NeedleRegrasp": "dvrk_psm_x2", "BiPegTransfer": "dvrk_psm_x2", "NeedleRings": "dvrk_psm_x2", "ECMReach": "dvrk_ecm",
               "MisOrient": "dvrk_ecm", "StaticTrack": "dvrk_ecm", "ActiveTrack": "dvrk_ecm"}


@pytest.mark.parametrize("task", list(TASKS))
def test_names_match_spaces(task):
    env = gym.make(env_id(task))
    try:
        names = dimension_names(env)
        spaces = env.observation_space
        assert len(names.state) == spaces["observation"].shape[0]
        assert len(names.achieved_goal) == len(names.desired_goal) == spaces["desired_goal"].shape[0]
        assert len(names.action) == env.action_space.shape[0]
        for group in (names.state, names.action, (*names.achieved_goal, *names.desired_goal)):
            assert len(set(group)) == len(group) and not any(n.startswith("s") and n[1:].isdigit() for n in group)
        assert names.robot_type == ROBOT_TYPES.get(task, "dvrk_psm")
    finally:
        env.close()


def test_needle_pick_state_layout_matches_the_names():
    """The names say what the numbers are: the tip, the jaw, the needle and the needle relative to the tip."""
    env = gym.make("SurRoL/NeedlePick-v0")
    try:
        obs, _ = env.reset(seed=3)
        named = dict(zip(dimension_names(env).state, obs["observation"], strict=True))
        base = env.unwrapped
        assert np.allclose([named["tip_x"], named["tip_y"], named["tip_z"]], base.tip_pose()[:3, 3], atol=1e-6)
        assert named["jaw"] == pytest.approx(base.psm.jaw_angle(), abs=1e-6)
        needle = np.array([named[f"needle_{c}"] for c in "xyz"])
        rel = np.array([named[f"needle_from_tip_{c}"] for c in "xyz"])
        assert np.allclose(rel, needle - base.tip_pose()[:3, 3], atol=1e-6)
        assert np.allclose([named[f"needle_waypoint_{c}"] for c in "xyz"], obs["achieved_goal"], atol=1e-6)
        features = features_for(env)
        assert features["observation.state"]["names"][:3] == ["tip_x", "tip_y", "tip_z"]
        assert features["observation.environment_state"]["names"] == [
            "needle_waypoint_x", "needle_waypoint_y", "needle_waypoint_z", "goal_x", "goal_y", "goal_z"]
    finally:
        env.close()

"""The adaptive sub-steps refine a period only where a tool can reach something (tool_sweep.py) or an object is
fast near something; leaving a slow held object out of the per-step checks changes nothing."""

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import adaptive_steps
from surrol_data.envs.physics import pb
from surrol_data.envs.psm_env import PsmEnv

_TOOL_LINKS = (4, 6, 7)


def _oracle_episode(env, seed: int) -> list:
    u = env.unwrapped
    obs, _ = env.reset(seed=seed)
    trace, done = [obs["observation"].copy()], False
    while not done:
        obs, _, terminated, truncated, _ = env.step(u.oracle_action(obs))
        trace.append(obs["observation"].copy())
        done = terminated or truncated
    return trace


def test_a_tool_moving_away_from_a_wall_beside_it_is_not_refined(monkeypatch):
    """GauzeRetrieve's tool starts 6.5 mm from the tray's −x wall, 1 cm above its top, and first moves away from
    it and down towards the gauze, 3 cm below: the distance-only test refines each of those moves, the
    directional one at most one (its bound is conservative: with the reference base yaw these moves also turn the
    wrist's joints, ~2° a step, which widens the bound for one period as the tool passes the wall)."""
    refined = {}
    for directional in (False, True):
        monkeypatch.setattr(adaptive_steps, "DIRECTIONAL_TOOL_TEST", directional)
        env = gym.make("SurRoL/GauzeRetrieve-v0")
        u = env.unwrapped
        obs, _ = env.reset(seed=2)
        before = u._substeps.refined_steps
        for _ in range(6):
            obs, *_ = env.step(u.oracle_action(obs))
        refined[directional] = u._substeps.refined_steps - before
        env.close()
    assert refined[False] == 6 * 12 and refined[True] <= 12


def test_a_tool_driven_down_at_the_gauze_is_still_refined():
    env = gym.make("SurRoL/GauzeRetrieve-v0")
    u = env.unwrapped
    env.reset(seed=1)
    top = u.gauze_pose()[0] + [0.0, 0.0, 0.0015]
    for _ in range(25):   # to 8 mm above the gauze's top, slowly
        err = (top + [0.0, 0.0, 0.008] - u.tip_pose()[:3, 3]) / 0.01
        if np.linalg.norm(err) < 0.03:
            break
        env.step(np.array([*np.clip(err, -0.6, 0.6), 0.0, 0.5], np.float32))
    before = u._substeps.refined_steps
    env.step(np.array([0.0, 0.0, -1.0, 0.0, 0.5], np.float32))
    assert u._substeps.refined_steps > before
    env.close()


def test_leaving_slow_held_objects_out_of_the_speed_checks_changes_no_episode(monkeypatch):
    traces = {}
    for skip in (False, True):
        monkeypatch.setattr(adaptive_steps, "SKIP_SLOW_HELD_OBJECTS", skip)
        env = gym.make("SurRoL/GauzeRetrieve-v0")
        traces[skip] = _oracle_episode(env, seed=3)
        env.close()
    assert len(traces[False]) == len(traces[True])
    assert all(np.array_equal(a, b) for a, b in zip(traces[False], traces[True]))


class _GatedContacts:
    """Counts the periods the directional test let through unrefined (the distance-only test would have refined
    them) in which a tool link then touched another body, and the closest such a link came (scaled)."""

    def __init__(self):
        self.gated = self.touched = 0
        self.closest = np.inf
        self._now = False
        self._touch = False

    def install(self, monkeypatch):
        travel = adaptive_steps.SubstepPlanner._tool_travel

        def both(planner, dt):
            monkeypatch.setattr(adaptive_steps, "DIRECTIONAL_TOOL_TEST", False)
            omni = travel(planner, dt)
            monkeypatch.setattr(adaptive_steps, "DIRECTIONAL_TOOL_TEST", True)
            directional = travel(planner, dt)
            self.touched += self._now and self._touch
            self._now, self._touch = bool(omni) and not directional, False
            self.gated += self._now
            return directional

        monkeypatch.setattr(adaptive_steps.SubstepPlanner, "_tool_travel", both)

    def __call__(self, env):
        if not self._now:
            return
        c, planner = env.client, env._substeps
        held = {g.object_id for g in planner.grasps if g.attached}
        tools = {g.psm.body for g in planner.grasps}
        for i in range(c.getNumBodies()):
            other = c.getBodyUniqueId(i)
            if other in held or other in tools:
                continue
            for tool in tools:
                for p in pb.getClosestPoints(tool, other, 0.05, physicsClientId=c._client):
                    if p[3] in _TOOL_LINKS:
                        self.closest = min(self.closest, p[8])
                        self._touch |= p[8] <= 0.0


@pytest.mark.slow
@pytest.mark.parametrize("task", ["GauzeRetrieve", "NeedlePick", "PegTransfer"])
def test_no_tool_touches_anything_in_a_period_the_directional_test_left_unrefined(task, monkeypatch):
    """Random and bang-bang actions and the oracle, 3 episodes each: in every period the directional test let
    through (and the distance-only test would have refined), the tools stayed clear of everything (measured:
    ≥ 4 mm real over 6 episodes of each, GauzeRetrieve and NeedlePick)."""
    probe = _GatedContacts()
    probe.install(monkeypatch)
    monkeypatch.setattr(PsmEnv, "substep_hook", probe)
    env = gym.make(f"SurRoL/{task}-v0")
    u = env.unwrapped
    rng = np.random.default_rng(0)
    for policy in ("oracle", "random", "bang-bang"):
        for seed in range(3):
            obs, _ = env.reset(seed=seed)
            done, t, action = False, 0, np.zeros(5)
            while not done:
                if policy == "oracle":
                    action = u.oracle_action(obs)
                elif policy == "random":
                    action = rng.uniform(-1, 1, 5)
                elif t % int(rng.integers(1, 5)) == 0:
                    action = np.sign(rng.uniform(-1, 1, 5))
                t += 1
                obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
                done = terminated or truncated
    env.close()
    assert probe.gated > 0
    assert probe.touched == 0 and probe.closest > 0.0

"""An arm that carries its object and touches nothing is moved by its motors' closed-form rule (free_motion.py): the
rule must be what PyBullet's own step does to the arm in such a period, and periods where it is not (a motor at its
force limit, a contact within reach) must be left to PyBullet."""

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import adaptive_steps, physics
from surrol_data.envs.free_motion import FreeMotion
from surrol_data.envs.physics import pb
from surrol_data.envs.psm import MOTOR_FORCE_LIMITS
from surrol_data.envs.psm_env import PsmEnv

from oracle_episode import run_oracle

_LIMITS = np.array(MOTOR_FORCE_LIMITS)


def _held_action(policy: str, rng, oracle):
    if policy == "oracle":
        return oracle
    a = rng.uniform(-1, 1, 5) if policy == "random" else np.sign(rng.uniform(-1, 1, 5))
    a[4] = -1.0   # keep holding
    return a.astype(np.float32)


@pytest.mark.parametrize("policy", ["oracle", "random", "bang-bang"])
def test_closed_form_periods_are_what_pybullet_steps(monkeypatch, policy):
    """Every period the planner would move in closed form is stepped by PyBullet instead, and compared with the
    closed form after each physics step: no contact pushes on the arm, joints within 5e-5 (rad; scaled m for
    insertion; PyBullet's solver leaves ~2.5e-5 of the coupled wrist rows unsolved), every motor's force within its
    limit (the closed form holds only then) and within 10 % of its limit of the force predicted (FORCE_MARGIN leaves
    20 %). Under bang-bang input motors do reach their limits in free air: those periods were refused."""
    # per period offered to the closed form: [motion or None, forces, deviations, prediction errors, contact forces]
    periods = []

    def plan_but_step(self, grasp, steps, hook):
        states = self._substeps.joint_states(grasp.psm, physics.TIME_STEP)
        periods.append([FreeMotion.plan(grasp.psm, states, steps, physics.TIME_STEP, grasp.load_torque), [], [], [],
                        []])
        return False

    def compare(env):
        if not periods or len(periods[-1][1]) >= physics.SUBSTEPS:
            return
        motion, forces, deviations, errors, pushes = periods[-1]
        cid = env.client._client
        states = pb.getJointStates(env.psm.body, range(8), physicsClientId=cid)
        pushes.append(max((c[9] for c in pb.getContactPoints(env.psm.body, physicsClientId=cid)), default=0.0))
        applied = np.array([s[3] for s in states])
        forces.append((np.abs(applied) / _LIMITS).max())
        if motion is not None:
            i = len(forces) - 1
            deviations.append(np.abs(np.array([s[0] for s in states]) - motion.positions[i]).max())
            errors.append((np.abs(applied - motion.forces[i]) / _LIMITS).max())

    monkeypatch.setattr(PsmEnv, "_move_free", plan_but_step)
    env = gym.make("SurRoL/GauzeRetrieve-v0")
    u = env.unwrapped
    u.substep_hook = compare
    rng = np.random.default_rng(0)
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        for _ in range(50):
            periods.append([None, [0.0] * physics.SUBSTEPS, [], [], []])   # (a full record: no period offered yet)
            a = u.oracle_action(obs)
            obs, *_ = env.step(_held_action(policy, rng, a) if u.grasp.attached else a)
    env.close()
    moved = [p for p in periods if p[0] is not None]
    assert len(moved) >= (2 if policy == "bang-bang" else 20)
    assert max(max(p[4]) for p in moved) == 0.0
    assert max(max(p[2]) for p in moved) < 5e-5
    assert max(max(p[1]) for p in moved) < 1.0
    assert max(max(p[3]) for p in moved) < 0.1
    if policy == "bang-bang":
        assert any(p[0] is None and max(p[1]) >= 0.999 for p in periods)   # saturated: refused


def test_most_of_the_oracles_carry_is_closed_form_and_it_still_succeeds():
    env = gym.make("SurRoL/GauzeRetrieve-v0")
    u = env.unwrapped
    successes = [bool(run_oracle(env, seed).successes[-1]) for seed in range(5)]
    p = u._substeps
    assert all(successes)
    assert p.free_periods >= 0.8 * p.carried_periods > 0
    env.close()


def test_without_it_pybullet_steps_every_period(monkeypatch):
    monkeypatch.setattr(adaptive_steps, "FREE_ARM_MOTION", False)
    env = gym.make("SurRoL/GauzeRetrieve-v0")
    u = env.unwrapped
    assert run_oracle(env, 0).successes[-1]
    assert u._substeps.carried_periods > 0 and u._substeps.free_periods == 0
    env.close()

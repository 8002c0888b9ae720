"""The envs' fast paths compute exactly what the plain numpy/PyBullet code they replace computes, bit for bit.

Speed work on the step loop must not change an episode (benchmarks/env_fingerprint.py checks whole episodes of
every task); these tests pin the pieces: the numeric helpers against numpy, the PSM's FK/IK against the textbook
formulas written with ``@``, ``np.linalg.norm`` and ``np.clip``, the client's cached bindings, and that dropping
PyBullet's renderer from a world that never renders leaves its episodes as they are.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the envs)
from surrol_data.envs import kinematics as kin
from surrol_data.envs import numeric, physics


def _random_arrays(rng, count=3000):
    for i in range(count):
        n = int(rng.integers(1, 11))
        shape = (n,) if i % 2 else (int(rng.integers(1, 5)), n)
        scale = 10.0 ** int(rng.integers(-6, 6))
        yield (rng.normal(size=shape) * scale).astype(np.float32 if i % 3 == 0 else np.float64)


def test_numeric_helpers_equal_numpy_bit_for_bit():
    rng = np.random.default_rng(0)
    for x in _random_arrays(rng):
        assert np.array_equal(numeric.norm(x), np.linalg.norm(x, axis=-1))
        if x.ndim == 1 and x.dtype == np.float64:
            assert numeric.vector_norm(x) == np.linalg.norm(x)
        assert np.array_equal(numeric.all_last(x > 0), np.all(x > 0, axis=-1))
        low, high = -np.abs(x).mean(), np.abs(x).mean() / 2
        assert np.array_equal(numeric.clip(x, low, high), np.clip(x, low, high))
    assert np.isnan(numeric.clip(np.array([np.nan]), -1.0, 1.0)[0])
    assert numeric.norm([3, 4]) == 5.0   # integers are taken as floats, as numpy does


def _fk_reference(q):
    t = np.eye(4)
    for row, qi in zip(kin.PSM_DH, q):
        t = t @ kin.dh_fixed_transform(row) @ (_trans_z(qi) if row[4] else _rot_z(qi))
    return t @ kin.TOOL_TIP_OFFSET


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans_z(z):
    t = np.eye(4)
    t[2, 3] = z
    return t


def _ik_reference(tip_pose):
    r6 = tip_pose[:3, :3] @ kin.TOOL_TIP_OFFSET[:3, :3].T
    p6 = tip_pose[:3, 3] - r6 @ kin.TOOL_TIP_OFFSET[:3, 3]
    z6 = r6[:, 2]
    radial = p6 - np.dot(p6, z6) * z6
    p5 = p6 - kin.WRIST_LENGTH * radial / np.linalg.norm(radial)
    depth = np.linalg.norm(p5)
    s = p5 / depth
    q1, q2, q3 = np.arctan2(s[0], -s[2]), np.arcsin(np.clip(-s[1], -1.0, 1.0)), depth + kin.SHAFT_END_OFFSET
    t = np.eye(4)
    for row, qi in zip(kin.PSM_DH[:3], (q1, q2, q3)):
        t = t @ kin.dh_fixed_transform(row) @ (_trans_z(qi) if row[4] else _rot_z(qi))
    m = t[:3, :3].T @ r6
    q = np.array([q1, q2, q3, np.arctan2(m[1, 2], m[0, 2]), np.arcsin(np.clip(-m[2, 2], -1.0, 1.0)),
                  np.arctan2(m[2, 0], m[2, 1])])
    return q, bool(np.all(q >= kin.PSM_LOWER - 1e-9) and np.all(q <= kin.PSM_UPPER + 1e-9))


def test_psm_fk_ik_and_euler_angles_equal_the_textbook_formulas_bit_for_bit():
    rng = np.random.default_rng(1)
    lower, upper = kin.PSM_LOWER.copy(), kin.PSM_UPPER.copy()
    lower[2], upper[2] = 0.05, 0.24
    outside = 0
    for i in range(600):
        q = rng.uniform(lower - 0.2, upper + 0.2)
        pose = kin.psm_fk(q)
        assert np.array_equal(pose, _fk_reference(q))
        if i % 2:   # the envs' commands: the tool pointing down, whose rotation has exact zeros (signed, in the bits)
            pose[:3, :3] = kin.tool_down_rotation(rng.uniform(-np.pi, np.pi) if i % 4 == 1 else 0.0)
        result = kin.psm_ik(pose)
        q_ref, ok_ref = _ik_reference(pose)
        assert result.q.tobytes() == q_ref.tobytes() and result.within_limits == ok_ref
        outside += not ok_ref
        rotation = pose[:3, :3]
        euler_ref = np.array([np.arctan2(rotation[2, 1], rotation[2, 2]),
                              np.arcsin(np.clip(-rotation[2, 0], -1.0, 1.0)),
                              np.arctan2(rotation[1, 0], rotation[0, 0])])
        assert kin.euler_xyz(rotation).tobytes() == euler_ref.tobytes()
    assert 0 < outside < 600      # both sides of the limit test were exercised


def test_client_binds_each_function_once_and_forgets_on_disconnect():
    client = physics.make_client()
    cid = client._client
    first = client.getNumBodies
    assert client.getNumBodies is first and first() == physics.pb.getNumBodies(physicsClientId=cid)
    body = client.createMultiBody(1.0, client.createCollisionShape(physics.pb.GEOM_SPHERE, radius=0.1))
    assert client.getNumBodies() == 1 and client.getBasePositionAndOrientation(body)[1] == (0.0, 0.0, 0.0, 1.0)
    client.disconnect()
    assert "getNumBodies" not in vars(client)      # no binding to a client id PyBullet may hand on


def _episode(env, seed=3, steps=30):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs["observation"]]
    for k in range(steps):
        action = env.unwrapped.oracle_action(obs) if k % 2 else rng.uniform(-1, 1, 5).astype(np.float32)
        obs, reward, *_ = env.step(action)
        out += [obs["observation"], np.float32(reward)]
    env.close()
    return np.concatenate([np.atleast_1d(x) for x in out])


@pytest.mark.parametrize("task", ["NeedlePick", "GauzeRetrieve"])
def test_a_world_without_renderer_gives_the_same_episode_as_a_rendered_one(task):
    # render_mode builds visual shapes and keeps PyBullet's renderer; the default env has neither.
    plain = _episode(gym.make(f"SurRoL/{task}-v0"))
    rendered = _episode(gym.make(f"SurRoL/{task}-v0", render_mode="rgb_array"))
    assert np.array_equal(plain, rendered)

"""The envs' fast paths compute what the plain numpy/PyBullet code they replace computes (within stated ULPs).

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


# Floating-point tolerances between the fast paths and the numpy forms. On this project's usual CPUs they agree bit
# for bit, but numpy picks its transcendental kernels by CPU (on AVX-512 its own SIMD arcsin/arctan2, within a few
# ULPs of the C library's) and BLAS its summation order, so across CPUs the forms agree only to a few units in the
# last place (ULP) of their results.
ULPS = 4                  # math.asin/atan2 vs numpy's kernels, on identical inputs
IK_ULPS_OF_ONE = 64       # joint values: a few ULPs of the inputs, carried through two chained rotations
WRIST_POSE_TOL = 1e-12     # tip poses reached by the two IK solutions, away from the tool-down singularity
TOOL_DOWN_POSE_TOL = 1e-7  # at the tool-down singularity asin(±1 − ε) moves by √(2ε) ≈ 2e-8 rad per ULP of input


def _ulps(a, b) -> np.ndarray:
    """|a − b| in units of the last place of the larger magnitude (0 for equal values, signed zeros included)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.abs(a - b) / np.spacing(np.maximum(np.abs(a), np.abs(b)))


def test_psm_fk_ik_and_euler_angles_equal_the_textbook_formulas_within_ulps():
    rng = np.random.default_rng(1)
    lower, upper = kin.PSM_LOWER.copy(), kin.PSM_UPPER.copy()
    lower[2], upper[2] = 0.05, 0.24
    outside = 0
    eps = np.finfo(np.float64).eps
    for i in range(600):
        q = rng.uniform(lower - 0.2, upper + 0.2)
        pose = kin.psm_fk(q)
        assert np.all(np.abs(pose - _fk_reference(q)) <= IK_ULPS_OF_ONE * eps)
        tool_down = bool(i % 2)
        if tool_down:   # the envs' commands: the tool pointing down, whose rotation has exact zeros (signed)
            pose[:3, :3] = kin.tool_down_rotation(rng.uniform(-np.pi, np.pi) if i % 4 == 1 else 0.0)
        result = kin.psm_ik(pose)
        q_ref, ok_ref = _ik_reference(pose)
        # the outer joints and the insertion follow from the position: well conditioned everywhere
        assert np.all(np.abs(result.q[:3] - q_ref[:3]) <= IK_ULPS_OF_ONE * eps), (i, result.q - q_ref)
        # the wrist joints are ill-conditioned near its singularity (atan2 of two small entries), so they are
        # compared by the tip pose they reach
        tol = TOOL_DOWN_POSE_TOL if tool_down else WRIST_POSE_TOL
        assert np.all(np.abs(kin.psm_fk(result.q) - kin.psm_fk(q_ref)) <= tol), (i, result.q - q_ref)
        near_limit = np.any(np.minimum(np.abs(q_ref - kin.PSM_LOWER), np.abs(q_ref - kin.PSM_UPPER)) < 1e-6)
        assert result.within_limits == ok_ref or near_limit
        outside += not ok_ref
        rotation = pose[:3, :3]
        euler_ref = np.array([np.arctan2(rotation[2, 1], rotation[2, 2]),
                              np.arcsin(np.clip(-rotation[2, 0], -1.0, 1.0)),
                              np.arctan2(rotation[1, 0], rotation[0, 0])])
        assert np.all(_ulps(kin.euler_xyz(rotation), euler_ref) <= ULPS), i
    assert 0 < outside < 600      # both sides of the limit test were exercised


def test_ulps_counts_units_in_the_last_place():
    assert _ulps(1.0, np.nextafter(1.0, 2.0)) == 1 and _ulps(0.0, -0.0) == 0
    assert _ulps(1e-300, 1e-300 * (1 + 8 * np.finfo(float).eps)) >= 4


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

"""Fingerprint of an env's behaviour: a hash of every observation, reward and info of seeded episodes.

Speed work must not change what the envs do, and runs of a long study are only comparable while the env behaves
the same: a change is checked by fingerprinting before and after it **on one machine** (floating-point bits differ
between CPUs, so two machines' fingerprints of the same code may differ). Per task, one env runs ``episodes``
oracle episodes then ``episodes`` episodes of seeded uniform random actions back to back (so state left over from
an earlier episode would show), each episode reset with its own seed.
"""

from __future__ import annotations

import hashlib

import numpy as np


def feed(h, value) -> None:
    """Add ``value`` (nested dicts, lists, arrays, scalars, None) to the hash ``h``: keys, dtypes, shapes and bytes.
    Anything numpy holds as Python objects is refused: its bytes would be memory addresses, different in every
    process."""
    if value is None:
        h.update(b"None")
    elif isinstance(value, dict):
        for key in sorted(value):
            h.update(str(key).encode())
            feed(h, value[key])
    elif isinstance(value, (list, tuple)):
        for v in value:
            feed(h, v)
    else:
        a = np.asarray(value)
        if a.dtype == object:
            raise TypeError(f"cannot fingerprint {type(value).__name__} values (numpy holds them as objects); "
                            "convert them to numbers first")
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())


def env_fingerprint(task: str, episodes: int = 2) -> str:
    """Hex digest over every (obs, reward, terminated, truncated, info) of the task's seeded episodes."""
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.envs import env_id

    env = gym.make(env_id(task))
    h = hashlib.sha256()
    oracle = env.unwrapped.oracle_action
    try:
        for policy in ("oracle", "random"):
            for seed in range(episodes):
                rng = np.random.default_rng(1000 + seed)
                obs, info = env.reset(seed=seed)
                feed(h, (obs, info))
                done = False
                while not done:
                    if policy == "oracle":
                        action = oracle(obs)
                    else:
                        action = rng.uniform(-1.0, 1.0, env.action_space.shape).astype(np.float32)
                    obs, reward, terminated, truncated, info = env.step(action)
                    feed(h, (obs, reward, terminated, truncated, info))
                    done = terminated or truncated
    finally:
        env.close()
    return h.hexdigest()

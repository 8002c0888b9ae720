"""The proficiency metrics a recording stores with each episode, computed for every episode of a dataset at once.

``validate`` checks the stored ``provenance/success``, ``steps_to_success``, ``path_length_cm``, ``jaw_closures``,
``clutch_uses`` and ``episode_steps`` against the frames. Computing them one episode at a time (a Trajectory, then
every metric of :func:`surrol_data.datasets.metrics.trajectory_proficiency`) cost ~6 ms an episode, a minute at
10,000 episodes; here each is one pass of numpy over all frames, with the very definitions of
:func:`~surrol_data.datasets.metrics.proficiency` (``tests/test_episode_metrics.py`` holds the two to each other).
"""

from __future__ import annotations

import numpy as np

STORED = ("success", "steps_to_success", "path_length_cm", "jaw_closures", "clutch_uses", "episode_steps")


def _per_episode_sum(values: np.ndarray, episode: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(episode, weights=values.astype(np.float64), minlength=n)


def _rising_edges(flag: np.ndarray, first: np.ndarray, episode: np.ndarray, n: int) -> np.ndarray:
    """Off→on transitions per episode of a flag (N,) or (N, k) (summed over columns); each episode starts off."""
    flag = flag.reshape(len(flag), -1)
    before = np.roll(flag, 1, axis=0)
    before[first] = False
    return np.rint(_per_episode_sum((flag & ~before).sum(axis=1), episode, n)).astype(np.int64)


def recorded_metrics(lengths: np.ndarray, success: np.ndarray, action: np.ndarray, tip: np.ndarray,
                     next_tip: np.ndarray, clutch: np.ndarray | None, n_arms: int) -> dict[str, np.ndarray]:
    """:data:`STORED` per episode (arrays of len(lengths)) of episodes stored one after the other: ``lengths``
    frames each; per frame ``success`` (N,), ``action`` (N, act_dim), ``tip``/``next_tip`` (N, n_arms*3) the tool
    tip before and after the action, ``clutch`` (N,) or None."""
    lengths = np.asarray(lengths, np.int64)
    n, frames = len(lengths), int(lengths.sum())
    episode = np.repeat(np.arange(n), lengths)
    starts = np.cumsum(lengths) - lengths
    t = np.arange(frames) - np.repeat(starts, lengths)
    first = t == 0
    last = t == np.repeat(lengths, lengths) - 1

    success = np.asarray(success).reshape(-1).astype(bool)
    hits = np.flatnonzero(success)
    steps_to_success = np.full(n, -1, np.int64)
    hit_episodes, at = np.unique(episode[hits], return_index=True)
    steps_to_success[hit_episodes] = t[hits[at]] + 1

    # the tip path is the T+1 positions tip[0..T-1], next_tip[T-1]; up to success it ends at position k
    tip = np.asarray(tip, np.float32).astype(np.float64).reshape(frames, n_arms, 3)
    after = np.roll(tip, -1, axis=0)
    after[last] = np.asarray(next_tip, np.float32).astype(np.float64).reshape(frames, n_arms, 3)[last]
    step = np.linalg.norm(after - tip, axis=-1)                      # (N, n_arms)
    k = steps_to_success[episode]
    counted = (k <= 0) | (t < k)
    path_cm = sum(100.0 * _per_episode_sum(step[:, arm] * counted, episode, n) for arm in range(n_arms))

    action = np.asarray(action).reshape(frames, -1)
    if action.size and action.shape[1] % 5 == 0:   # the jaw command is the last action dimension of each arm
        jaw = action.reshape(frames, n_arms, -1)[:, :, -1].astype(np.float64) < 0
        closures = _rising_edges(jaw, first, episode, n)
    else:
        closures = np.zeros(n, np.int64)
    clutches = (_rising_edges(np.asarray(clutch).reshape(-1).astype(bool), first, episode, n) if clutch is not None
                else np.zeros(n, np.int64))
    return {"success": steps_to_success > 0, "steps_to_success": steps_to_success,
            "path_length_cm": np.asarray(path_cm, np.float64) if n else np.zeros(0),
            "jaw_closures": closures, "clutch_uses": clutches, "episode_steps": lengths}

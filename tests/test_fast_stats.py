"""The recorder's per-episode statistics (surrol_data.datasets.fast_stats) are lerobot's own, bit for bit: values,
dtypes and shapes, on the columns an episode holds and on degenerate ones (constant, two frames, narrow ranges)."""

import numpy as np
import pytest

from surrol_data.datasets.fast_stats import episode_stats
from surrol_data.datasets.lerobot_compat import same_stats


def compute_episode_stats(episode, features):
    """lerobot's own statistics. Imported here, not at the top, so that collecting the suite does not pay for
    lerobot's import (~10 s of CPU: torchvision, diffusers); the tests that record datasets import it anyway."""
    from lerobot.datasets.compute_stats import compute_episode_stats as theirs

    return theirs(episode, features)


def _episode(rng, T):
    return {
        "observation.state": rng.normal(size=(T, 19)).astype(np.float32),
        "action": np.clip(rng.normal(size=(T, 5)), -1, 1).astype(np.float32),
        "narrow": (1.0 + 1e-7 * rng.normal(size=(T, 3))).astype(np.float32),     # edges collapse in float32
        "constant": np.full((T, 2), 0.25, np.float32),
        "zero": np.zeros((T, 1), np.float32),
        "ties": rng.integers(0, 3, size=(T, 4)).astype(np.float32),
        "next.reward": rng.normal(size=T).astype(np.float32),
        "next.done": np.arange(T) == T - 1,
        "flag": rng.random((T, 2)) < 0.3,
        "timestamp": (np.arange(T) / 5).astype(np.float32),
        "index": np.arange(100, 100 + T, dtype=np.int64),
        "wide": (rng.normal(size=(T, 2)) * 1e6).astype(np.float64),
    }


def _features(ep):
    return {k: {"dtype": str(v.dtype), "shape": v.shape[1:] or (1,)} for k, v in ep.items()}


@pytest.mark.parametrize("T", [2, 3, 7, 50, 101, 333])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_episode_stats_are_lerobots_bit_for_bit(T, seed):
    ep = _episode(np.random.default_rng(seed * 1000 + T), T)
    ours = episode_stats(ep, _features(ep))
    assert ours is not None
    assert same_stats(ours, compute_episode_stats(ep, _features(ep)))


@pytest.mark.parametrize("seed", [3, 4])
def test_columns_without_a_constant_one_take_the_vectorised_edges_and_still_match(seed):
    ep = {k: v for k, v in _episode(np.random.default_rng(seed), 40).items() if k not in ("constant", "narrow")}
    assert same_stats(episode_stats(ep, _features(ep)), compute_episode_stats(ep, _features(ep)))


def test_what_is_not_reproduced_is_left_to_lerobot():
    ep = {"x": np.ones((1, 3), np.float32)}                       # one frame: lerobot's basic-stats path
    assert episode_stats(ep, _features(ep)) is None
    ep = {"x": np.array([[1.0], [np.nan]], np.float32)}
    assert episode_stats(ep, _features(ep)) is None
    ep = {"x": np.zeros((4, 3), np.float32)}
    assert episode_stats(ep, {"x": {"dtype": "image", "shape": (3,)}}) is None


def test_a_mismatch_is_caught():
    ep = _episode(np.random.default_rng(5), 20)
    ours = episode_stats(ep, _features(ep))
    theirs = compute_episode_stats(ep, _features(ep))
    theirs["action"]["q50"] = theirs["action"]["q50"] + 1e-7
    assert not same_stats(ours, theirs)


def test_the_guessed_bin_is_the_counted_one():
    """The bin search guesses from the even spacing and checks exactly; on edges of every scale, values on an edge
    and constant columns it gives the brute count lerobot's searchsorted gives."""
    from surrol_data.datasets.fast_stats import _edges, _edges_at_or_below

    rng = np.random.default_rng(7)
    lo = rng.normal(size=3000).astype(np.float32)
    scale = rng.choice([0.0, 1e-7, 1e-3, 1.0, 1e3], 3000).astype(np.float32)
    hi = lo + np.abs(rng.normal(size=3000)).astype(np.float32) * scale
    edges = _edges(lo, hi)
    x = (lo + (hi - lo) * rng.random(3000)).astype(np.float32)
    x[:300] = edges[np.arange(300), rng.integers(0, 5001, 300)]
    assert (_edges_at_or_below(edges, x) == (edges <= x[:, None]).sum(axis=1)).all()

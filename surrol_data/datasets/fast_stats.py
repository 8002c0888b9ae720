"""lerobot's per-episode statistics of vector features, computed with whole-array numpy: :func:`episode_stats`.

``lerobot.datasets.compute_stats.compute_episode_stats`` estimates each column's quantiles from a 5000-bin histogram
(``RunningQuantileStats``): per column a ``linspace`` of edges, an ``np.histogram``, then per quantile a ``cumsum``
of the 5000 bins and a search — ~80 columns an episode for NeedlePick, ~22 ms, two thirds of what recording an episode
cost. The quantile only needs the histogram's cumulative counts at two bins, and those are counts of frames below an
edge: ``cumsum[j]`` is the number of values below edge ``j + 1`` (``np.histogram`` with array bins counts with
``searchsorted`` on the sorted values), so with ``k = ceil(q * n)`` the bin lerobot's search lands in is the one the
``k``-th smallest value falls in. Everything else is lerobot's arithmetic on the same arrays, in the same order and
dtypes (the edges from the same ``linspace`` call per column), so the result is bit for bit lerobot's:
``tests/test_fast_stats.py`` checks that on random and degenerate columns, and the recorder checks it again on the
first episode of every feature set it writes (:func:`surrol_data.datasets.lerobot_compat.install_fast_save`).

Anything outside what is reproduced here (images, strings, fewer than 2 frames, non-finite values, other quantiles
or bin counts) returns None, and the caller uses lerobot's function.
"""

from __future__ import annotations

import math

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)   # lerobot.datasets.compute_stats.DEFAULT_QUANTILES
BINS = 5000                                  # RunningQuantileStats' num_quantile_bins


def episode_stats(episode_data: dict, features: dict) -> dict | None:
    """``compute_episode_stats(episode_data, features)`` for an episode of numeric features, or None."""
    batches, stats = {}, {}
    for key, data in episode_data.items():
        dtype = features[key]["dtype"]
        if dtype in {"string", "language"}:
            continue
        if dtype in {"image", "video"} or not isinstance(data, np.ndarray) or data.ndim not in (1, 2):
            return None
        batch = _prepared(data)
        if batch is None:
            return None
        batches[key] = batch
        stats[key] = _moments(batch)
    # The quantiles of every column of one dtype at once (column by column the arithmetic is the same).
    for dtype in {b.dtype for b in batches.values()}:
        keys = [k for k, b in batches.items() if b.dtype == dtype]
        quantiles = _quantiles(np.concatenate([batches[k] for k in keys], axis=1),
                               np.concatenate([stats[k]["min"] for k in keys]),
                               np.concatenate([stats[k]["max"] for k in keys]))
        if quantiles is None:
            return None
        first = 0
        for k in keys:
            width = batches[k].shape[1]
            cut = slice(first, first + width)
            for q, (plain, edge, value) in zip(QUANTILES, quantiles):
                # lerobot gathers one scalar per column with np.array: the edges' dtype when every column of the
                # feature returned its bin edge, float64 as soon as one was interpolated
                stats[k][f"q{int(q * 100):02d}"] = edge[cut].copy() if plain[cut].all() else value[cut].copy()
            first += width
    for key, data in episode_data.items():   # _reshape_stats_by_axis: a (T,) feature keeps a (1,) axis
        if key in stats and data.ndim == 1:
            stats[key] = {k: v if k == "count" else v.reshape(1) for k, v in stats[key].items()}
    return stats


def _prepared(data: np.ndarray) -> np.ndarray | None:
    """The (n, D) batch RunningQuantileStats.update works on, or None where lerobot takes another path."""
    batch = data.reshape(-1, 1) if data.ndim == 1 else data
    if batch.shape[0] < 2 or batch.dtype.kind not in "biuf":
        return None
    batch = batch.astype(np.result_type(batch.dtype, np.float32), copy=False)
    return batch if np.isfinite(batch).all() else None


def _moments(batch: np.ndarray) -> dict:
    """RunningQuantileStats.update on its first batch, then get_statistics, less the quantiles."""
    n = batch.shape[0]
    mean = np.mean(batch, axis=0)
    mean_sq = np.mean(batch**2, axis=0)
    lo, hi = np.min(batch, axis=0), np.max(batch, axis=0)
    mean += (np.mean(batch, axis=0) - mean) * (n / n)
    mean_sq += (np.mean(batch**2, axis=0) - mean_sq) * (n / n)
    return {"min": lo.copy(), "max": hi.copy(), "mean": mean.copy(),
            "std": np.sqrt(np.maximum(0, mean_sq - mean**2)), "count": np.array([n])}


def _edges(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Each column's ``np.linspace(lo - 1e-10, hi + 1e-10, BINS + 1)``, as rows. One vectorised call gives the same
    values as one call per column as long as no step is 0 (linspace then switches every column to another formula),
    so the columns with a zero step (a constant column whose padding vanished in float32) get one call each."""
    start, stop = lo - 1e-10, hi + 1e-10
    zero = np.subtract(stop, start) / BINS == 0
    if not zero.any():
        return np.linspace(start, stop, BINS + 1, axis=-1)
    edges = np.empty((len(lo), BINS + 1), dtype=np.result_type(start, stop, 1.0))
    if not zero.all():
        edges[~zero] = np.linspace(start[~zero], stop[~zero], BINS + 1, axis=-1)
    for i in np.flatnonzero(zero):
        edges[i] = np.linspace(start[i], stop[i], BINS + 1)
    return edges


def _quantiles(batch: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[tuple] | None:
    """Per quantile: which columns lerobot answers with a bin edge, those edges, and every column's float64 value."""
    n, columns = batch.shape
    edges = _edges(lo, hi)
    if edges.dtype != batch.dtype or (edges[:, :-1] > edges[:, 1:]).any():
        return None   # np.histogram would compare in another dtype, or refuse the bins
    ordered = np.sort(batch, axis=0)
    cols = np.arange(columns)
    results = []
    for q in QUANTILES:
        target = q * n
        kth = ordered[math.ceil(target) - 1]                       # the k-th smallest value of each column
        idx = np.minimum(_edges_at_or_below(edges, kth) - 1, BINS - 1)
        low_edge, high_edge = edges[cols, idx], edges[cols, np.minimum(idx + 1, BINS)]
        before = (ordered < low_edge[None, :]).sum(axis=0).astype(np.float64)            # cumsum[idx - 1]
        through = np.where(idx < BINS - 1, (ordered < high_edge[None, :]).sum(axis=0), n).astype(np.float64)
        in_bin = through - before
        plain = (idx == 0) | (in_bin == 0)                          # lerobot returns the bin's lower edge
        with np.errstate(divide="ignore", invalid="ignore"):
            fraction = (target - before) / in_bin
            interpolated = low_edge + fraction * (high_edge - low_edge)
        results.append((plain, low_edge, np.where(plain, low_edge.astype(np.float64), interpolated)))
    return results


def _edges_at_or_below(edges: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per row, how many of its (non-decreasing) edges are <= ``x[row]``: lerobot's ``searchsorted`` of the bins.

    The edges are evenly spaced, so the answer is guessed from the spacing and then checked exactly against the two
    edges around it; rows whose guess fails the check (rounding, a zero step) are counted edge by edge."""
    rows = np.arange(len(x))
    first, last = edges[:, 0].astype(np.float64), edges[:, -1].astype(np.float64)
    with np.errstate(all="ignore"):
        guess = np.floor((x.astype(np.float64) - first) / ((last - first) / BINS))
    guess = np.clip(np.nan_to_num(guess, nan=0.0, posinf=BINS, neginf=0.0), 0, BINS).astype(np.int64)
    ok = (edges[rows, guess] <= x) & ((guess == BINS) | (edges[rows, np.minimum(guess + 1, BINS)] > x))
    count = guess + 1
    if not ok.all():
        bad = ~ok
        count[bad] = (edges[bad] <= x[bad, None]).sum(axis=1)
    return count

"""numpy's small-array operations that the envs run every step, without numpy's per-call Python overhead.

Each function computes exactly what the numpy call it names computes, with the same ufuncs in the same order
(so the same bits): on the envs' 3- to 10-element arrays numpy's argument handling and dispatch cost more
than the arithmetic, and a step makes dozens of such calls.
"""

from __future__ import annotations

import numpy as np


def clip(a: np.ndarray, low, high) -> np.ndarray:
    """``np.clip(a, low, high)`` of a float array: max with ``low``, then min with ``high``, NaN kept."""
    return np.minimum(np.maximum(a, low), high)


def norm(x) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` of a real array (single vectors and batches)."""
    x = np.asarray(x)
    if x.dtype.kind != "f":
        x = x.astype(float)
    return np.sqrt(np.add.reduce(x * x, axis=-1))


def vector_norm(v: np.ndarray):
    """``np.linalg.norm(v)`` of one real float vector: the square root of its dot product with itself."""
    return np.sqrt(v.dot(v))


def all_last(b) -> np.ndarray:
    """``np.all(b, axis=-1)`` of a boolean array."""
    return np.logical_and.reduce(b, axis=-1)

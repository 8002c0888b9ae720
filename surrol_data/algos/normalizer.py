"""Running mean/std normaliser for observations and goals (DEX/baselines style, reference §1.2).

Statistics are global running sums over every sample ever added (never reset, never decayed), so the
normalisation of a state changes only as more data arrives. Sums are float64: float32 sums of
hundreds of thousands of squared positions lose the digits the variance lives in.

    mean = sum / count
    std  = sqrt(max(eps², sumsq / count − mean²))
    normalize(x) = clip((x − mean) / std, −clip, +clip)

``eps`` keeps a feature that never varies (e.g. the blocked jaw of NeedleReach) from being divided by
zero; ``clip`` bounds what an out-of-distribution state can feed the network.
"""

from __future__ import annotations

import numpy as np
import torch


def standardize(x, mean: np.ndarray, std: np.ndarray, clip: float) -> np.ndarray:
    """clip((x − mean) / std, −clip, +clip) as float32, computed in float64 (``mean``/``std`` broadcast against
    ``x``: one row of statistics, or one per row of ``x``)."""
    return np.clip((np.asarray(x, np.float64) - mean) / std, -clip, clip).astype(np.float32)


class Normalizer:
    def __init__(self, size: int, eps: float = 0.01, clip: float = 5.0):
        if size <= 0:
            raise ValueError(f"Normalizer size must be positive, got {size}")
        self.size = int(size)
        self.eps = float(eps)
        self.clip = float(clip)
        self.sum = np.zeros(self.size, np.float64)
        self.sumsq = np.zeros(self.size, np.float64)
        self.count = 0
        self.mean = np.zeros(self.size, np.float64)
        self.std = np.ones(self.size, np.float64)

    def update(self, x: np.ndarray) -> None:
        """Add samples (shape (size,) or (..., size)) to the running sums and recompute mean/std."""
        x = self._as_rows(x)
        self.sum += x.sum(axis=0)
        self.sumsq += np.square(x).sum(axis=0)
        self.count += len(x)
        self._recompute()

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """Normalised float32 copy of ``x``, same shape as given."""
        x = np.asarray(x, np.float64)
        if x.shape[-1:] != (self.size,):
            raise ValueError(f"Normalizer expects a last dimension of {self.size}, got shape {x.shape}")
        return standardize(x, self.mean, self.std, self.clip)

    def state_dict(self) -> dict:
        # Tensors and plain scalars only, so a checkpoint holding this loads with torch.load(weights_only=True).
        return {
            "size": self.size, "eps": self.eps, "clip": self.clip, "count": self.count,
            "sum": torch.from_numpy(self.sum.copy()), "sumsq": torch.from_numpy(self.sumsq.copy()),
        }

    def load_state_dict(self, state: dict) -> None:
        if int(state["size"]) != self.size:
            raise ValueError(f"cannot load normaliser statistics of size {state['size']} into one of size {self.size}")
        self.eps = float(state["eps"])
        self.clip = float(state["clip"])
        self.count = int(state["count"])
        self.sum = np.asarray(state["sum"], np.float64).copy()
        self.sumsq = np.asarray(state["sumsq"], np.float64).copy()
        self._recompute()

    @classmethod
    def from_state_dict(cls, state: dict) -> Normalizer:
        norm = cls(int(state["size"]))
        norm.load_state_dict(state)
        return norm

    def _as_rows(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if x.shape[-1:] != (self.size,):
            raise ValueError(f"Normalizer expects a last dimension of {self.size}, got shape {x.shape}")
        x = x.reshape(-1, self.size)
        if not np.all(np.isfinite(x)):
            raise ValueError("Normalizer.update got NaN or inf values; check the data source")
        return x

    def _recompute(self) -> None:
        if self.count == 0:
            return
        self.mean = self.sum / self.count
        var = self.sumsq / self.count - np.square(self.mean)
        self.std = np.sqrt(np.maximum(self.eps**2, var))

    def __repr__(self) -> str:
        return f"Normalizer(size={self.size}, count={self.count}, eps={self.eps}, clip={self.clip})"

"""Train / validation split of episodes, stratified by provenance so every operator and skill is in both.

Used by ``surrol-data split`` (two datasets) and by the robomimic export (``mask/train``, ``mask/valid``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

STRATIFY_BY = ("source", "skill", "operator_id")


def split_episodes(episodes: pd.DataFrame, valid_fraction: float = 0.1, seed: int = 0,
                   stratify_by: tuple[str, ...] = STRATIFY_BY) -> tuple[list[int], list[int]]:
    """(train, valid) episode indices, each sorted.

    Within each group of equal ``stratify_by`` values (columns missing from ``episodes`` are ignored) a
    seeded shuffle puts ``round(valid_fraction * n)`` episodes in valid, but never a group's only episode and
    never all of a group's episodes, so training sees every operator. Same input and seed, same split.
    """
    if not 0.0 < float(valid_fraction) < 1.0:
        raise ValueError(f"--valid-fraction must be between 0 and 1 (exclusive), got {valid_fraction}")
    keys = [k for k in stratify_by if k in episodes.columns]
    rng = np.random.default_rng(seed)
    train: list[int] = []
    valid: list[int] = []
    groups = episodes.groupby(keys, sort=True) if keys else [((), episodes)]
    for _, rows in groups:
        ids = rows["episode_index"].to_numpy(np.int64)
        ids = ids[rng.permutation(len(ids))]
        n_valid = min(int(round(valid_fraction * len(ids))), max(len(ids) - 1, 0))
        valid += ids[:n_valid].tolist()
        train += ids[n_valid:].tolist()
    return sorted(train), sorted(valid)

"""Per-episode journal: every finished episode is on disk the moment ``DatasetRecorder.record`` returns.

LeRobot keeps its parquet writers open and a parquet file is unreadable until its footer is written, so the
recorder only closes files at checkpoints (closing every episode would cost a pair of new files per
episode). Between checkpoints, each finished episode is also written here as one small ``.npz`` — the exact
:class:`Trajectory` arrays and the normalized provenance — by write-to-temp + ``os.replace``, so a kill
leaves either the whole entry or none. A checkpoint makes the episodes durable in the dataset's own files
and deletes their entries, so the journal holds about ``checkpoint_every`` files (up to
``MAX_UNSAVED_WHILE_IMPORTING`` of a new dataset while lerobot is imported in the background).
:func:`surrol_data.datasets.repair.repair` replays the entries a hard kill left behind.

Measured by ``benchmarks/dataset_io.py`` (the write speed with the journal on) and
``benchmarks/crash_safety.py`` (what a SIGKILL leaves).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from surrol_data.datasets.trajectory import Trajectory

JOURNAL_DIR = ".surrol_data_journal"
_ARRAYS = ("observation", "achieved_goal", "desired_goal", "action", "reward", "success", "terminated",
           "tip_position", "jaw_angle")


def journal_dir(root: str | Path) -> Path:
    return Path(root) / JOURNAL_DIR


def entry_path(root: str | Path, episode_index: int) -> Path:
    return journal_dir(root) / f"episode_{int(episode_index):06d}.npz"


def write_entry(root: str | Path, episode_index: int, traj: Trajectory, provenance: dict) -> Path:
    """Atomically write episode ``episode_index`` (its trajectory and full provenance)."""
    path = entry_path(root, episode_index)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {name: np.asarray(getattr(traj, name)) for name in _ARRAYS}
    arrays.update({f"flag.{k}": np.asarray(v) for k, v in traj.flags.items()})
    arrays.update({f"image.{k}": np.asarray(v) for k, v in traj.images.items()})
    if traj.policy_action is not None:
        arrays["policy_action"] = np.asarray(traj.policy_action)
    arrays["provenance"] = np.asarray(json.dumps(provenance, sort_keys=True))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)  # uncompressed: ~1 ms for a state-only episode
    os.replace(tmp, path)
    return path


def read_entry(path: str | Path) -> tuple[Trajectory, dict]:
    """(trajectory, provenance) of a journal entry; raises ValueError if it is damaged."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        provenance = json.loads(str(data.pop("provenance")))
        traj = Trajectory(**{name: data.pop(name) for name in _ARRAYS}, policy_action=data.pop("policy_action", None),
                          flags={k.removeprefix("flag."): v for k, v in data.items() if k.startswith("flag.")},
                          images={k.removeprefix("image."): v for k, v in data.items() if k.startswith("image.")})
    except Exception as e:  # a damaged entry is reported by the caller, whatever numpy raised
        raise ValueError(f"journal entry {path} is damaged ({type(e).__name__}: {e})") from None
    return traj, provenance


def entries(root: str | Path) -> list[tuple[int, Path]]:
    """(episode index, path) of every complete entry, in episode order (half-written ``.tmp`` files ignored)."""
    folder = journal_dir(root)
    if not folder.is_dir():
        return []
    found = []
    for path in folder.glob("episode_*.npz"):
        try:
            found.append((int(path.stem.split("_")[1]), path))
        except ValueError:
            continue
    return sorted(found)


def drop_below(root: str | Path, episodes: int) -> None:
    """Delete the entries of episodes ``< episodes`` (they are durable in the dataset files now)."""
    for index, path in entries(root):
        if index < episodes:
            path.unlink(missing_ok=True)
    folder = journal_dir(root)
    if folder.is_dir():
        for tmp in folder.glob("*.tmp"):
            tmp.unlink(missing_ok=True)
        if not any(folder.iterdir()):
            folder.rmdir()

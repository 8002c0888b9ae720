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

import contextlib
import json
import os
import shutil
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
    return write_entry_at(path, traj, provenance)


def write_entry_at(path: Path, traj: Trajectory, provenance: dict) -> Path:
    """Atomically write one entry at ``path`` (its folder exists)."""
    arrays = {name: np.asarray(getattr(traj, name)) for name in _ARRAYS}
    arrays.update({f"flag.{k}": np.asarray(v) for k, v in traj.flags.items()})
    arrays.update({f"image.{k}": np.asarray(v) for k, v in traj.images.items()})
    if traj.policy_action is not None:
        arrays["policy_action"] = np.asarray(traj.policy_action)
    arrays["provenance"] = np.asarray(json.dumps(provenance, sort_keys=True))
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)  # uncompressed: ~1 ms for a state-only episode
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):   # a full disk: leave no half entry behind (it would be ignored anyway)
            os.unlink(tmp)
        raise
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
        if not entries(root):
            (folder / RENUMBERED).unlink(missing_ok=True)
        if not any(folder.iterdir()):
            folder.rmdir()


# ---------------------------------------------------------------- renumbering (the repair's)
# A repair that keeps episodes 0..k-1 in place writes every salvaged episode again after them, renumbered k, k+1, ...
# Its writer journals each one under its new number: were the journal still numbered the old way, an entry written
# under a new number could replace one not yet replayed (old 60 written as new 50 over old 50...), and a repair
# stopped halfway (a full disk) would leave one episode under two numbers. So the repair first renumbers the journal
# itself, as a whole: every salvaged episode under its new number, in RENAMING, then swapped for the journal in
# two renames; the RENUMBERED marker (the first new number) says that from it on the journal, not the files, holds
# the dataset's episodes.

RENAMING = JOURNAL_DIR + ".next"
RENUMBERED = "renumbered_from"


def renumbered_from(root: str | Path) -> int | None:
    """The first episode index from which the journal (renumbered by a repair) supersedes the files; None if not."""
    try:
        return int((journal_dir(root) / RENUMBERED).read_text())
    except (OSError, ValueError):
        return None


def finish_renumbering(root: str | Path) -> None:
    """Complete or undo a renumbering a kill interrupted (see above): the new journal, once whole (its marker is
    written last), replaces an old one already moved away; otherwise it is discarded (the old one is intact)."""
    root = Path(root)
    staged = root / RENAMING
    if not staged.exists():
        return
    if not journal_dir(root).exists() and (staged / RENUMBERED).exists():
        os.replace(staged, journal_dir(root))
    else:
        shutil.rmtree(staged)


def renumber(root: str | Path, items: list[tuple[Path | None, object, dict]], first: int, backup: Path) -> None:
    """Make the journal hold ``items`` as episodes ``first``, ``first + 1``, ...: each item is (its current entry,
    or None, and then the trajectory and provenance to write). The old journal is moved into ``backup``."""
    root = Path(root)
    staged = root / RENAMING
    if staged.exists():
        shutil.rmtree(staged)
    staged.mkdir()
    for i, (source, traj, provenance) in enumerate(items):
        dest = staged / entry_path(root, first + i).name
        if source is not None:
            try:
                os.link(source, dest)   # the same bytes: an entry does not hold its own number
            except OSError:
                shutil.copyfile(source, dest)
        else:
            write_entry_at(dest, traj, provenance)
    tmp = staged / (RENUMBERED + ".tmp")
    tmp.write_text(str(first))
    os.replace(tmp, staged / RENUMBERED)   # the new journal is whole
    if journal_dir(root).exists():
        backup.mkdir(parents=True, exist_ok=True)
        os.replace(journal_dir(root), backup / JOURNAL_DIR)
    os.replace(staged, journal_dir(root))

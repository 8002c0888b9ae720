"""Fewer, larger files once a recording finishes: :func:`consolidate`, and its crash recovery.

Why: the recorder checkpoints every few episodes (:mod:`surrol_data.datasets.writer`), and each checkpoint closes
lerobot's parquet files and continues in new ones. A 10,000-episode recording with a checkpoint every 10 episodes
leaves 1,000 data files and 1,000 ``meta/episodes`` files, and every command that opens the dataset pays per file:
a ``meta/episodes`` footer describes ~230 columns (the per-episode statistics lerobot's ``aggregate_stats`` reads)
and costs milliseconds to parse, ~5 s for the 1,000 of them before anything is checked.

What: when a recording session ends, the files it wrote (those that were not there when it opened) are rewritten
into as few files as lerobot's own size limit allows (``data_files_size_in_mb`` of ``info.json``; file indices
roll over into the next chunk after ``chunks_size``), numbered from the session's first file, as lerobot would
have numbered them had it never been checkpointed. The data files keep lerobot's layout (one row group per
episode, :func:`write_one_row_group_per_episode`); a ``meta/episodes`` file is one
row group, as ``aggregate_datasets`` writes it. Each metadata row's ``data/chunk_index``/``data/file_index`` and
``meta/episodes/chunk_index``/``meta/episodes/file_index`` name its new files; nothing else changes (frames, global
indices, statistics, provenance, seals, videos, ``info.json``).

Crash safety: the new files are written (and synced) under ``<root>/.surrol_data_consolidating/new/``, outside the
folders lerobot and surrol_data read; then ``plan.json`` is written atomically — the commit point — naming the
files to take out and the files to put in; then each old file is moved to ``.../old/`` and each new file into
place, and the folder is removed. A kill before the plan leaves the dataset as it was (the half-built folder is
discarded); a kill after it leaves a plan that :func:`finish_interrupted` carries out again, every step of which
may be repeated (an old file already moved is not moved twice; a new file already in place is not looked for
again). The folder's presence is a sign of a killed recording (:func:`surrol_data.datasets.repair.killed_recording`),
so every command repairs it first, and :func:`surrol_data.datasets.repair.repair` starts with
:func:`finish_interrupted`: no episode is lost at any moment.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from surrol_data.datasets.reader import DATA_DIR, EPISODES_DIR, INFO_PATH, parquet_files

STAGING_DIR = ".surrol_data_consolidating"
_PLAN = "plan.json"
_DATA_LOCATION = ("data/chunk_index", "data/file_index")
_META_LOCATION = ("meta/episodes/chunk_index", "meta/episodes/file_index")


def dataset_files(root: str | Path) -> set[str]:
    """The data and ``meta/episodes`` parquet files of ``root`` (relative paths): what a session found at its start,
    so that :func:`consolidate` rewrites only what the session wrote."""
    root = Path(root)
    return {p.relative_to(root).as_posix() for sub in (DATA_DIR, EPISODES_DIR) for p in parquet_files(root, sub)}


def interrupted(root: str | Path) -> bool:
    """Whether a consolidation of ``root`` was killed before it finished (see the module doc)."""
    return (Path(root) / STAGING_DIR).exists()


def _indices(rel: str) -> tuple[int, int]:
    chunk, file = Path(rel).parent.name, Path(rel).stem
    return int(chunk.split("-")[1]), int(file.split("-")[1])


def next_file(chunk: int, file: int, chunks_size: int) -> tuple[int, int]:
    """The (chunk, file) indices after these: lerobot's ``update_chunk_file_indices`` (not imported here, where
    lerobot is not otherwise needed)."""
    return (chunk + 1, 0) if file == chunks_size - 1 else (chunk, file + 1)


def _groups(paths: list[Path], limit_bytes: float) -> list[list[Path]]:
    """Consecutive runs of ``paths`` of about ``limit_bytes`` each (lerobot starts a new file at its size limit)."""
    groups: list[list[Path]] = [[]]
    size = 0
    for path in paths:
        if groups[-1] and size + path.stat().st_size > limit_bytes:
            groups.append([])
            size = 0
        groups[-1].append(path)
        size += path.stat().st_size
    return [g for g in groups if g]


def _numbered(first: str, count: int, pattern: str, chunks_size: int) -> list[str]:
    chunk, file = _indices(first)
    names = []
    for _ in range(count):
        names.append(pattern.format(chunk_index=chunk, file_index=file))
        chunk, file = next_file(chunk, file, chunks_size)
    return names


def write_one_row_group_per_episode(table: pa.Table, path: Path) -> None:
    """``table`` (frames, in episode order) as a data file of lerobot's layout: one row group per episode, which the
    reader relies on to read one episode alone (lerobot's ``write_table_one_row_group_per_episode``, without the
    import of lerobot it costs)."""
    episodes = table.column("episode_index").to_numpy()
    starts = np.concatenate([[0], np.flatnonzero(np.diff(episodes)) + 1, [len(episodes)]])
    with pq.ParquetWriter(path, table.schema, compression="snappy", use_dictionary=True) as writer:
        for start, stop in zip(starts[:-1], starts[1:], strict=True):
            writer.write_table(table.slice(int(start), int(stop - start)))


def _write_synced(write, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write(path)
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def set_column(table: pa.Table, name: str, values) -> pa.Table:
    """``table`` with column ``name`` replaced by ``values``, in the column's own type."""
    at = table.column_names.index(name)
    field = table.schema.field(at)
    return table.set_column(at, field, pa.array(values, field.type))


def _plan(root: Path, staging: Path, keep: set[str], progress) -> dict | None:
    """Write the consolidated files under ``staging/new``; the plan, or None when there is nothing to gain or the
    files do not have the layout this rewrites (then nothing is changed)."""
    info = json.loads((root / INFO_PATH).read_text())
    limit = float(info.get("data_files_size_in_mb") or 100) * 1024 * 1024
    chunks_size = int(info.get("chunks_size") or 1000)
    data_paths = [p for p in parquet_files(root, DATA_DIR) if p.relative_to(root).as_posix() not in keep]
    meta_paths = [p for p in parquet_files(root, EPISODES_DIR) if p.relative_to(root).as_posix() not in keep]
    kept_files = sorted(keep)
    data_rel = [p.relative_to(root).as_posix() for p in data_paths]
    meta_rel = [p.relative_to(root).as_posix() for p in meta_paths]
    if not data_paths or not meta_paths or (len(data_paths) < 2 and len(meta_paths) < 2):
        return None   # nothing to gain (or not a session's data and metadata together: left as they are)
    # Only a tail of each folder is renumbered: a kept file after a rewritten one would collide with the new names.
    for rels, sub in ((data_rel, DATA_DIR), (meta_rel, EPISODES_DIR)):
        if rels and any(k.startswith(sub + "/") and k > rels[0] for k in kept_files):
            return None
    meta = pa.concat_tables([pq.read_table(p, use_threads=False) for p in progress(meta_paths, "metadata")],
                            promote_options="default").sort_by("episode_index")
    if not meta.num_rows or not set(_DATA_LOCATION + _META_LOCATION) <= set(meta.column_names):
        return None
    said = [info["data_path"].format(chunk_index=int(c), file_index=int(f)) for c, f in zip(
        meta.column(_DATA_LOCATION[0]).to_pylist(), meta.column(_DATA_LOCATION[1]).to_pylist(), strict=True)]
    if set(said) != set(data_rel):
        return None   # the session's metadata rows and data files are not the same episodes: leave them

    new: list[str] = []
    data_groups = _groups(data_paths, limit)
    data_names = _numbered(data_rel[0], len(data_groups), info["data_path"], chunks_size)
    moved_to: dict[str, str] = {}
    episodes = pc.unique(meta.column("episode_index"))
    for group, name in zip(progress(data_groups, "frames"), data_names, strict=True):
        table = pa.concat_tables([pq.read_table(p, use_threads=False) for p in group]).sort_by("index")
        if not pc.all(pc.is_in(pc.unique(table.column("episode_index")), episodes)).as_py():
            return None   # frames of an episode whose metadata row is in a file kept as it is: leave them
        _write_synced(lambda path, t=table: write_one_row_group_per_episode(t, path), staging / "new" / name)
        new.append(name)
        moved_to.update({p.relative_to(root).as_posix(): name for p in group})
    new_location = [_indices(moved_to[rel]) for rel in said]
    meta = set_column(meta, _DATA_LOCATION[0], [c for c, _ in new_location])
    meta = set_column(meta, _DATA_LOCATION[1], [f for _, f in new_location])

    per_row = sum(p.stat().st_size for p in meta_paths) / meta.num_rows
    rows_per_file = max(1, int(limit // max(per_row, 1.0)))
    starts = list(range(0, meta.num_rows, rows_per_file))
    meta_names = _numbered(meta_rel[0], len(starts), "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}"
                                                     ".parquet", chunks_size)
    for start, name in zip(starts, meta_names, strict=True):
        part = meta.slice(start, rows_per_file)
        chunk, file = _indices(name)
        part = set_column(part, _META_LOCATION[0], [chunk] * part.num_rows)
        part = set_column(part, _META_LOCATION[1], [file] * part.num_rows)
        _write_synced(lambda path, t=part: pq.write_table(t, path), staging / "new" / name)
        new.append(name)
    return {"remove": data_rel + meta_rel, "add": new}


def consolidate(root: str | Path, keep: set[str] | None = None, *, show_progress: bool = False) -> bool:
    """Rewrite the data and ``meta/episodes`` files of ``root`` not in ``keep`` (relative paths, from
    :func:`dataset_files`; None: every file) into as few files as lerobot's size limit allows (see the module doc).
    True when the files changed. The dataset must be finished and not open elsewhere (the recorder calls this
    holding its lock, after lerobot's ``finalize``). A failure before the commit point changes nothing and is
    raised; the half-built files are removed."""
    root = Path(root)
    keep = set() if keep is None else set(keep)
    staging = root / STAGING_DIR
    if staging.exists():
        finish_interrupted(root)

    def progress(items, what):
        if not show_progress:
            return items
        from tqdm import tqdm

        return tqdm(items, desc=f"consolidating {what}", unit="file", leave=False)

    try:
        plan = _plan(root, staging, keep, progress)
        if plan is None:
            shutil.rmtree(staging, ignore_errors=True)
            return False
        _write_plan(staging, plan)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)   # before the commit point: the dataset is untouched
        raise
    _apply(root, staging, plan)
    return True


def _write_plan(staging: Path, plan: dict) -> None:
    tmp = staging / (_PLAN + ".tmp")
    with open(tmp, "w") as fh:
        json.dump(plan, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, staging / _PLAN)   # the commit point
    fd = os.open(staging, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _apply(root: Path, staging: Path, plan: dict) -> None:
    """Carry out ``plan``; every step may be repeated after a kill (see the module doc)."""
    for rel in plan["remove"]:
        aside = staging / "old" / rel
        if not aside.exists() and (root / rel).exists():   # moved already: what is there now is a new file
            aside.parent.mkdir(parents=True, exist_ok=True)
            os.replace(root / rel, aside)
    for rel in plan["add"]:
        src = staging / "new" / rel
        if src.exists():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, root / rel)
    for sub in (DATA_DIR, EPISODES_DIR):   # chunk folders the new numbering left empty
        for folder in sorted((root / sub).glob("chunk-*")):
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
    shutil.rmtree(staging)


def finish_interrupted(root: str | Path) -> str:
    """Finish or undo a consolidation of ``root`` a kill interrupted; what was done ("" when there was none)."""
    root = Path(root)
    staging = root / STAGING_DIR
    if not staging.exists():
        return ""
    try:
        plan = json.loads((staging / _PLAN).read_text())
        if not isinstance(plan, dict) or not {"remove", "add"} <= plan.keys():
            raise ValueError("not a plan")
    except (OSError, ValueError):
        shutil.rmtree(staging)   # killed before the commit point: the dataset's own files were never touched
        return "an interrupted consolidation of the files was undone (the files are as they were)"
    _apply(root, staging, plan)
    return (f"an interrupted consolidation of the files was completed ({len(plan['remove'])} files into "
            f"{len(plan['add'])})")


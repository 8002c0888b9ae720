"""Copy episodes of state-only datasets into a new dataset table by table: what ``filter``, ``split`` and
``merge --drop-duplicates`` write when no episode has camera frames.

Why: written again through the recorder, every episode is a ``save_episode`` of lerobot's (~10 ms of CPU), so a
10,000-episode ``split`` could not pass 100 episodes/s. But a kept episode's stored values do not change on the
way: its frames, its per-episode statistics, its provenance (content hash included) and its seal are the same
bytes in the new dataset (the content hash and the seal cover no index). Only where it is changes: its
``episode_index`` (renumbered 0..N-1 in the order given), each frame's global ``index``, the episode's
``dataset_from_index``/``dataset_to_index`` and the files it is in. So this reads the kept rows of the inputs'
data and ``meta/episodes`` files with pyarrow, renumbers those columns, and writes lerobot's layout (one row group
per episode in the data files, as lerobot's writer and ``aggregate_datasets`` write them; as few files as
``data_files_size_in_mb`` allows), ``info.json`` with the new totals, ``stats.json`` aggregated over the kept
episodes as lerobot's ``aggregate_stats`` does (:func:`aggregate_stats`), the tasks, the sidecar (one session, as the recorder writes it)
and the device traces. An input without seals gets them, as the recorder gives every new dataset.

A camera dataset still goes through the recorder (its video segments are decoded and encoded again). What the
inputs must be is checked before (:func:`surrol_data.datasets.merge.copy_episodes`: valid, compatible, the
episodes there). The dataset is built in a hidden folder beside ``out`` and renamed into place when complete, so
a killed copy leaves no output.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from surrol_data.datasets.consolidate import next_file, set_column
from surrol_data.datasets.reader import DATA_DIR, EPISODES_DIR, INFO_PATH, DatasetReader, column_to_numpy, parquet_files
from surrol_data.datasets.schema import PROVENANCE_COLUMNS, PROVENANCE_PREFIX, PROVENANCE_SEAL, SIDECAR_PATH

STAGING_SUFFIX = ".copying"
_TASKS = "meta/tasks.parquet"


def applies(readers: list[DatasetReader]) -> bool:
    """Whether the episodes of ``readers`` can be copied table by table: no camera (video or image) feature, and
    one table of tasks for all (the frames' ``task_index`` then means the same task in the output)."""
    if any(ft["dtype"] in ("video", "image") for r in readers for ft in r.features.values()):
        return False
    try:
        tasks = [pq.read_table(r.root / _TASKS) for r in readers]
    except (OSError, pa.ArrowInvalid):
        return False
    return all(t.equals(tasks[0]) for t in tasks[1:])


def staging_folder(out: Path) -> Path:
    return out.parent / f".{out.name}{STAGING_SUFFIX}"


def copy_state_episodes(readers: list[DatasetReader], selection: list[list[int]], out: Path, *, shared: dict,
                        command: str, derived_from: dict, progress: Callable[[int], None]) -> None:
    """Write the episodes ``selection[i]`` of ``readers[i]``, in order, as the new dataset ``out`` (see the module
    doc); ``progress(n)`` after each ``n`` episodes. ``derived_from`` goes into the sidecar, with ``episodes``: where
    each new episode came from."""
    from surrol_data.datasets.lock import DatasetLock, writer_pid
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.datasets.schema import utc_now_iso

    staging = staging_folder(out)
    if staging.exists():
        if writer_pid(staging) is not None:
            raise DatasetError(f"another command is writing {out} (pid {writer_pid(staging) or '?'}); wait for it")
        shutil.rmtree(staging)   # left by a killed copy: it never became an output
    staging.mkdir(parents=True)
    built = staging / "dataset"
    started = utc_now_iso()
    try:
        with DatasetLock(staging):
            built.mkdir()
            meta, origin = _write_tables(readers, selection, built, progress)
            derived_from = {**derived_from, "episodes": [
                {"episode": i, "source_root": str(reader.root), "source_episode": ep}
                for i, (reader, ep) in enumerate(origin)]}
            _write_metadata(readers[0], built, out, meta, shared=shared, command=command, derived_from=derived_from,
                            started=started)
            for i, (reader, ep) in enumerate(origin):
                copy_trace(reader.root, ep, built, i)
        built.rename(out)   # atomic: before it, no output; after it, the whole output
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _full_meta(reader: DatasetReader) -> tuple[pa.Table, dict[int, int]]:
    """Every ``meta/episodes`` row of ``reader`` (statistics included), and the row of each episode."""
    table = pa.concat_tables([pq.read_table(p) for p in parquet_files(reader.root, EPISODES_DIR)],
                             promote_options="default")
    return table, {int(e): i for i, e in enumerate(column_to_numpy(table.column("episode_index")))}


def _frames(reader: DatasetReader, episodes: list[int], columns: list[str]) -> pa.Table:
    """The frames of ``episodes`` (each data file read once), in the order given."""
    table = reader._read_episodes(sorted(set(episodes)), columns)
    ep_col = column_to_numpy(table.column("episode_index"))
    firsts, starts, counts = np.unique(ep_col, return_index=True, return_counts=True)
    where = {int(e): (int(s), int(n)) for e, s, n in zip(firsts, starts, counts, strict=True)}
    take = np.concatenate([np.arange(where[e][0], sum(where[e])) for e in episodes])
    return table.take(pa.array(take, pa.int64()))


def _shift_stats(meta: pa.Table, feature: str, delta: np.ndarray) -> pa.Table:
    """``stats/<feature>/*`` of each row moved by ``delta`` (the renumbered ``episode_index`` and ``index``: every
    value of the episode moves by the same amount, so its min, max, mean and quantiles do; std and count stay)."""
    for name in list(meta.column_names):
        stat = name.rsplit("/", 1)[-1]
        if not name.startswith(f"stats/{feature}/") or stat in ("std", "count"):
            continue
        column = meta.column(name).combine_chunks()
        lengths = pc.list_value_length(column).to_numpy(zero_copy_only=False)
        values = column.flatten().to_numpy(zero_copy_only=False) + np.repeat(delta, lengths)
        shifted = pa.ListArray.from_arrays(column.offsets, pa.array(values, column.type.value_type))
        meta = meta.set_column(meta.column_names.index(name), meta.schema.field(name), shifted)
    return meta


_BATCH = 2000


def _write_tables(readers, selection, built: Path, progress) -> tuple[pa.Table, list[tuple[DatasetReader, int]]]:
    """Data and ``meta/episodes`` files of the new dataset; (its metadata rows, (reader, source episode) of each
    new episode)."""
    info = readers[0].info
    limit = float(info.get("data_files_size_in_mb") or 100) * 1024 * 1024
    chunks_size = int(info.get("chunks_size") or 1000)
    columns = list(pq.read_schema(parquet_files(readers[0].root, DATA_DIR)[0]).names)
    origin: list[tuple[DatasetReader, int]] = []
    metas: list[pa.Table] = []
    data_file, file_bytes, frames_so_far = (0, 0), 0.0, 0
    writer: pq.ParquetWriter | None = None
    try:
        for reader, episodes in zip(readers, selection, strict=True):
            full_meta, row_of = _full_meta(reader)
            per_frame = (sum(p.stat().st_size for p in parquet_files(reader.root, DATA_DIR))
                         / max(int(reader.info["total_frames"]), 1))
            for at in range(0, len(episodes), _BATCH):
                batch = [int(e) for e in episodes[at:at + _BATCH]]
                frames = _frames(reader, batch, columns)
                meta = full_meta.take(pa.array([row_of[e] for e in batch], pa.int64()))
                lengths = column_to_numpy(meta.column("length")).astype(np.int64)
                new_ep = np.arange(len(origin), len(origin) + len(batch), dtype=np.int64)
                starts = frames_so_far + np.concatenate([[0], np.cumsum(lengths)[:-1]])
                frames = set_column(frames, "episode_index", np.repeat(new_ep, lengths))
                frames = set_column(frames, "index", np.arange(frames_so_far, frames_so_far + frames.num_rows))
                meta = _shift_stats(meta, "episode_index", new_ep - np.asarray(batch, np.int64))
                meta = _shift_stats(meta, "index", starts - column_to_numpy(meta.column("dataset_from_index")))
                chunk_col, file_col = np.empty(len(batch), np.int64), np.empty(len(batch), np.int64)
                row = 0
                for i, n in enumerate(lengths.tolist()):
                    if writer is not None and file_bytes + n * per_frame > limit:
                        writer.close()
                        writer, file_bytes = None, 0.0
                        data_file = next_file(*data_file, chunks_size)
                    if writer is None:
                        path = built / info["data_path"].format(chunk_index=data_file[0], file_index=data_file[1])
                        path.parent.mkdir(parents=True, exist_ok=True)
                        writer = pq.ParquetWriter(path, frames.schema, compression="snappy", use_dictionary=True)
                    writer.write_table(frames.slice(row, n))   # one episode, one row group: lerobot's layout
                    chunk_col[i], file_col[i] = data_file
                    file_bytes += n * per_frame
                    row += n
                for name, values in (("episode_index", new_ep), ("dataset_from_index", starts),
                                     ("dataset_to_index", starts + lengths), ("data/chunk_index", chunk_col),
                                     ("data/file_index", file_col)):
                    meta = set_column(meta, name, values)
                metas.append(_sealed(meta))
                origin += [(reader, ep) for ep in batch]
                frames_so_far += int(lengths.sum())
                progress(len(batch))
            del full_meta
    finally:
        if writer is not None:
            writer.close()
    meta = _write_meta(pa.concat_tables(metas, promote_options="default"), built, limit, chunks_size)
    return meta, origin


def _sealed(meta: pa.Table) -> pa.Table:
    """``meta`` with the provenance seal of each row (computed for an input recorded before seals existed)."""
    if PROVENANCE_SEAL in meta.column_names:
        return meta
    from surrol_data.datasets.schema import provenance_seal

    columns = {name: meta.column(PROVENANCE_PREFIX + name).to_pylist() for name in PROVENANCE_COLUMNS}
    seals = [provenance_seal({name: values[i] for name, values in columns.items()}) for i in range(meta.num_rows)]
    return meta.append_column(PROVENANCE_SEAL, pa.array(seals, pa.string()))


def _write_meta(meta: pa.Table, built: Path, limit: float, chunks_size: int) -> pa.Table:
    """``meta/episodes`` in files of about ``limit`` bytes, one row group each (as ``aggregate_datasets`` writes
    them); the rows as written."""
    rows_per_file = max(1, int(limit // max(meta.nbytes / max(meta.num_rows, 1), 1.0)))
    chunk, file = 0, 0
    parts = []
    for start in range(0, meta.num_rows, rows_per_file):
        part = meta.slice(start, rows_per_file)
        part = set_column(part, "meta/episodes/chunk_index", [chunk] * part.num_rows)
        part = set_column(part, "meta/episodes/file_index", [file] * part.num_rows)
        path = built / EPISODES_DIR / f"chunk-{chunk:03d}" / f"file-{file:03d}.parquet"
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(part, path)
        parts.append(part)
        chunk, file = next_file(chunk, file, chunks_size)
    return pa.concat_tables(parts)


def aggregate_stats(meta: pa.Table) -> dict[str, dict[str, np.ndarray]]:
    """The dataset statistics over the rows' per-episode ``stats/<feature>/<stat>`` columns: lerobot's
    ``compute_stats.aggregate_stats`` (the count-weighted mean, the parallel variance, min, max, count-weighted
    quantiles), computed column by column instead of episode by episode — and without importing lerobot, whose
    import (torch, diffusers) cost more CPU than the rest of a 5,000-episode copy."""
    columns: dict[str, dict[str, np.ndarray]] = {}
    for name in meta.column_names:
        if name.startswith("stats/"):
            _, feature, stat = name.split("/", 2)
            columns.setdefault(feature, {})[stat] = column_to_numpy(meta.column(name)).reshape(meta.num_rows, -1)
    out = {}
    for feature, stats in columns.items():
        counts = stats["count"]
        total = counts.sum(axis=0)
        mean = (stats["mean"] * counts).sum(axis=0) / total
        variance = ((stats["std"] ** 2 + (stats["mean"] - mean) ** 2) * counts).sum(axis=0) / total
        out[feature] = {"min": stats["min"].min(axis=0), "max": stats["max"].max(axis=0), "mean": mean,
                        "std": np.sqrt(variance), "count": total}
        for key in (k for k in stats if k.startswith("q") and k[1:].isdigit()):
            out[feature][key] = (stats[key] * counts).sum(axis=0) / total
    return out


def _write_metadata(source: DatasetReader, built: Path, out: Path, meta: pa.Table, *, shared: dict, command: str,
                    derived_from: dict, started: str) -> None:
    """info.json, stats.json, tasks, sidecar (one finished session) and card of the new dataset."""
    from surrol_data.datasets.card import write_dataset_card
    from surrol_data.datasets.hub_offline import local_repo_id
    from surrol_data.datasets.schema import package_version, utc_now_iso
    from surrol_data.datasets.writer import _write_json_atomic, git_commit, sidecar_facts

    shutil.copyfile(source.root / _TASKS, built / _TASKS)
    info = dict(source.info)
    info.update({"total_episodes": meta.num_rows, "total_frames": int(pc.sum(meta.column("length")).as_py()),
                 "total_tasks": pq.read_metadata(built / _TASKS).num_rows,
                 "splits": {"train": f"0:{meta.num_rows}"}})
    _write_json_atomic(built / INFO_PATH, info)
    stats = {feature: {k: v.tolist() for k, v in values.items()} for feature, values in aggregate_stats(meta).items()}
    (built / "meta" / "stats.json").write_text(json.dumps(stats, indent=4))   # as lerobot's write_stats writes it
    now = utc_now_iso()
    side = sidecar_facts(local_repo_id(out), shared["task"], shared["env_id"], shared["task_description"],
                         shared["robot_type"])
    side.update({"created_at": started, "seals": 1,
                 "sessions": [{"started_at": started, "command": command, "git_commit": git_commit(),
                               "package_version": package_version(), "first_episode": 0,
                               "episodes": meta.num_rows, "ended_at": now}],
                 "checkpoint": {"at": now, "episodes": meta.num_rows, "info": info},
                 "derived_from": derived_from})
    _write_json_atomic(built / SIDECAR_PATH, side)
    write_dataset_card(built)


def copy_trace(src_root: Path, src_ep: int, dst_root: Path, dst_ep: int) -> None:
    """A haptic episode's device trace goes with it, under its new index (the file holds no index itself)."""
    import shutil

    from surrol_data.datasets.repair import TRACE_DIR

    src = src_root / TRACE_DIR / f"episode_{src_ep:06d}.npz"
    if src.exists():
        dst = dst_root / TRACE_DIR / f"episode_{dst_ep:06d}.npz"
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)

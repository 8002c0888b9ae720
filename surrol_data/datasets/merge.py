"""Make new datasets out of existing ones — merge, filter, train/valid split — with provenance intact.

``merge`` goes through LeRobot's own :func:`lerobot.datasets.aggregate.aggregate_datasets`: it copies the data
parquet and the episodes metadata (every ``provenance/*`` column included, renumbered) and concatenates the
videos without re-encoding them. Around it, ours: before, the compatibility checks (one task, env id, fps, robot
type and feature set; no dataset given twice; no episode that is a copy of another) so a refusal names the
difference in our terms; after, the device traces (renumbered), the sidecar (``derived_from``: where each
episode came from) and the dataset card. It is written in a staging folder beside ``out`` and renamed into place
when complete, so a killed merge leaves no output (and never touches its inputs).

``filter`` and ``split`` keep a subset of episodes, which ``aggregate_datasets`` cannot do (and LeRobot's own
``dataset_tools.split_dataset`` / ``delete_episodes`` rebuild the episodes table and drop extra per-episode
columns; see shared/docs/reference/lerobot.md §2): every kept episode is read with
:class:`~surrol_data.datasets.reader.DatasetReader` and written again through
:class:`~surrol_data.datasets.recorder.DatasetRecorder` with *all* its provenance columns given explicitly, so
nothing is recomputed or lost. ``merge --drop-duplicates`` takes that path too (it leaves episodes out). Camera
frames are decoded by the reader and re-encoded (lossy, like any video re-encode).

Episode indices are renumbered 0..N-1 in the output; ``meta/surrol_data.json`` records where each one came from
(``derived_from``), and the card says so.
"""

from __future__ import annotations

import contextlib
import json
import shlex
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from surrol_data.datasets.bulk_copy import copy_trace
from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import (CAMERA_VERSION, DEFAULT_CAMERA_RENDERER, PROVENANCE_COLUMNS, SIDECAR_PATH,
                                         camera_renderer_of, camera_version_of)

_LEROBOT_DEFAULT_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def _user_features(info: dict) -> dict:
    return {k: {"dtype": v["dtype"], "shape": tuple(v["shape"]), "names": v.get("names")}
            for k, v in info["features"].items() if k not in _LEROBOT_DEFAULT_FEATURES}


def _task_description(root: Path, sidecar: dict) -> str:
    if sidecar.get("task_description"):
        return sidecar["task_description"]
    import pyarrow.parquet as pq

    tasks = pq.read_table(root / "meta" / "tasks.parquet").to_pandas()
    names = list(tasks.index if "task" not in tasks.columns else tasks["task"])
    if not names:
        raise DatasetError(f"{root}: no task description in {SIDECAR_PATH} or meta/tasks.parquet")
    return str(names[0])


def _check_compatible(readers: list[DatasetReader]) -> dict:
    """The shared facts (features, task, env id, ...) of the inputs, or DatasetError naming the difference."""
    first = readers[0]
    side = read_sidecar(first.root)
    if "env_id" not in side or "task" not in side:
        raise DatasetError(f"{first.root}: {SIDECAR_PATH} lacks task/env_id (not recorded by surrol_data?); "
                           "run `surrol-data validate` on it")
    missing = [k for k in PROVENANCE_COLUMNS if k not in first.episodes.columns]
    if missing:
        raise DatasetError(f"{first.root}: episodes lack provenance column(s) {missing}; run `surrol-data validate`")
    features = _user_features(first.info)
    for other in readers[1:]:
        other_side = read_sidecar(other.root)
        for key in ("task", "env_id"):
            if other_side.get(key) != side[key]:
                raise DatasetError(f"cannot combine {first.root} ({key}={side[key]!r}) with {other.root} "
                                   f"({key}={other_side.get(key)!r}): one dataset holds one task")
        for key in ("fps", "robot_type"):
            if other.info.get(key) != first.info.get(key):
                raise DatasetError(f"cannot combine {first.root} ({key}={first.info.get(key)!r}) with {other.root} "
                                   f"({key}={other.info.get(key)!r}): LeRobot datasets have one {key}")
        theirs = _user_features(other.info)
        diff = sorted(k for k in set(features) | set(theirs)
                      if k not in features or k not in theirs
                      or (features[k]["dtype"], features[k]["shape"]) != (theirs[k]["dtype"], theirs[k]["shape"]))
        if diff:
            raise DatasetError(f"cannot combine {first.root} with {other.root}: features differ in {diff}")
        renamed = sorted(k for k in features if _names(features[k]) != _names(theirs[k]))
        if renamed:
            raise DatasetError(f"cannot combine {first.root} with {other.root}: the dimension names of {renamed} "
                               "differ (datasets recorded by different versions?); bring both to the current "
                               "schema first")
        missing = [k for k in PROVENANCE_COLUMNS if k not in other.episodes.columns]
        if missing:
            raise DatasetError(f"{other.root}: episodes lack provenance column(s) {missing}")
        ours_v = camera_version_of(side, first.info["features"])
        theirs_v = camera_version_of(other_side, other.info["features"])
        if ours_v != theirs_v:
            raise DatasetError(f"cannot combine {first.root} (camera version {ours_v}) with {other.root} (camera "
                               f"version {theirs_v}): their endoscope images are turned and framed differently "
                               "(see surrol_data.datasets.schema.CAMERA_VERSION)")
        ours_r = camera_renderer_of(side, first.info["features"])
        theirs_r = camera_renderer_of(other_side, other.info["features"])
        if ours_r != theirs_r:
            raise DatasetError(f"cannot combine {first.root} (drawn by the {ours_r!r} renderer) with {other.root} "
                               f"(drawn by {theirs_r!r}): their endoscope images are not the same observation")
    return {"features": features, "task": side["task"], "env_id": side["env_id"],
            "camera_version": camera_version_of(side, first.info["features"]) or CAMERA_VERSION,
            "camera_renderer": camera_renderer_of(side, first.info["features"]) or DEFAULT_CAMERA_RENDERER,
            "task_description": _task_description(first.root, side),
            "robot_type": first.info.get("robot_type") or "dvrk_psm"}


def _refuse_out_inside(out: Path, inputs: list[Path]) -> None:
    """A new dataset written inside an input would become part of the folder it is read from (and of every later
    copy of it)."""
    where = out.resolve()
    for root in inputs:
        if where.is_relative_to(root):
            raise ValueError(f"--out {out} is inside the input dataset {root}: choose a folder outside it")


def _names(feature: dict):
    names = feature.get("names")
    return list(names.values())[0] if isinstance(names, dict) and len(names) == 1 else names


def copy_episodes(selection: list[tuple[str | Path, list[int]]], out: str | Path, *, operation: str,
                  where: str | None = None, command: str | None = None, progress: bool = True,
                  drop_duplicates: bool = False, _duplicates: list | None = None) -> Path:
    """Write the episodes ``selection`` = [(dataset root, [episode indices]) ...] into a new dataset ``out``.

    Inputs must share the task, env id and frame features, and pass the cheap validation checks. An episode
    whose content hash equals an earlier one's is refused (DatasetError), or skipped with ``drop_duplicates``.
    Returns ``out``. ``_duplicates``: pairs a caller already left out (recorded in the sidecar).
    """
    _duplicates = list(_duplicates or [])
    from surrol_data.datasets.card import write_dataset_card
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.writer import _write_json_atomic

    from surrol_data.datasets.guard import require_valid
    from surrol_data.datasets.output_path import new_output

    out = new_output(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists: choose a new output folder")
    _refuse_out_inside(out, [Path(r).resolve() for r, _ in selection])
    # cheap checks: a damaged input is refused before anything is written; read: the folder to read it from
    read = {root: require_valid(root) for root in dict.fromkeys(Path(r).resolve() for r, _ in selection)}
    readers = [DatasetReader(read[Path(root).resolve()]) for root, _ in selection]
    for reader, (_, episodes) in zip(readers, selection, strict=True):
        for ep in episodes:
            reader._episode_row(ep)  # DatasetError naming a missing episode, before anything is written
        if reader.root.resolve() == out.resolve():
            raise ValueError(f"the output {out} is one of the inputs")
    shared = _check_compatible(readers)
    selection, duplicates = _without_duplicates(readers, selection)
    duplicates = _duplicates + duplicates
    if duplicates and not drop_duplicates:
        raise _duplicates_error(operation, duplicates)
    total = sum(len(eps) for _, eps in selection)
    if total == 0:
        raise DatasetError(f"{operation}: no episode selected" + (f" by --where {where!r}" if where else "")
                           + "; nothing to write")
    command = command if command is not None else shlex.join(sys.argv)
    derived_from = {"operation": operation, "where": where or "",
                    "duplicates_dropped": [{"episode": b, "copy_of": a} for a, b in duplicates],
                    "sources": [{"root": str(r.root.resolve()), "episodes": len(eps)}
                                for r, (_, eps) in zip(readers, selection, strict=True)]}
    bar = tqdm(total=total, desc=f"{operation} -> {out.name}", unit="ep", disable=not progress)
    from surrol_data.datasets import bulk_copy

    if bulk_copy.applies(readers):   # state-only: the stored rows are copied, not recorded again
        try:
            bulk_copy.copy_state_episodes(readers, [eps for _, eps in selection], out, shared=shared,
                                          command=command, derived_from=derived_from, progress=bar.update)
        finally:
            bar.close()
        return out
    provenance_of = []
    recorder = DatasetRecorder(out, features=shared["features"], task=shared["task"], env_id=shared["env_id"],
                               task_description=shared["task_description"], robot_type=shared["robot_type"],
                               command=command, checkpoint_every=50, camera_version=shared["camera_version"],
                               camera_renderer=shared["camera_renderer"])
    try:
        with recorder:
            for reader, (_, episodes) in zip(readers, selection, strict=True):
                rows = {int(r["episode_index"]): r for r in reader.episodes.to_dict("records")}  # not .at per value
                for ep, traj in _read_in_batches(reader, episodes):
                    prov = {k: _plain(rows[ep][k]) for k in PROVENANCE_COLUMNS}
                    new_index = recorder.record(traj, prov)
                    copy_trace(reader.root, int(ep), out, new_index)
                    provenance_of.append({"episode": new_index, "source_root": str(reader.root), "source_episode": int(ep)})
                    bar.update(1)
    finally:
        bar.close()
    side = read_sidecar(out)
    side["derived_from"] = {**derived_from, "episodes": provenance_of}
    _write_json_atomic(out / SIDECAR_PATH, side)
    write_dataset_card(out)
    return out


_BATCH = 500


def _read_in_batches(reader: DatasetReader, episodes: list[int]):
    """(episode, its Trajectory with images) of ``episodes`` in order, a few hundred at a time: one read of each
    data file per batch instead of one per episode (a parquet footer parsed per episode cost ~5 ms), memory
    bounded."""
    for at in range(0, len(episodes), _BATCH):
        batch = [int(e) for e in episodes[at:at + _BATCH]]
        yield from zip(batch, reader.trajectories(batch, images=True), strict=True)


def _without_duplicates(readers, selection):
    """The selection without episodes whose content hash was seen earlier, and the (first, copy) pairs found."""
    seen: dict[str, str] = {}
    kept, duplicates = [], []
    for reader, (root, episodes) in zip(readers, selection, strict=True):
        hashes = dict(zip(reader.episodes["episode_index"].astype(int), reader.episodes["content_hash"], strict=True))
        mine = []
        for ep in episodes:
            label = f"{reader.root} episode {int(ep)}"
            digest = hashes[int(ep)]
            if digest in seen:
                duplicates.append((seen[digest], label))
            else:
                seen[digest] = label
                mine.append(ep)
        kept.append((root, mine))
    return kept, duplicates


def _plain(value):
    """pandas/numpy scalar -> python scalar (normalize_provenance checks exact types)."""
    return value.item() if isinstance(value, np.generic) else value


def merge_datasets(out: str | Path, inputs: list[str | Path], *, command: str | None = None,
                   progress: bool = True, drop_duplicates: bool = False) -> Path:
    """All episodes of ``inputs``, in order, into the new dataset ``out`` (see the module doc).

    Refused with DatasetError before anything is written: a dataset given twice, inputs that differ in task, env
    id, fps, robot type or features, and episodes equal in content to an earlier one (unless ``drop_duplicates``,
    which keeps the first copy and writes the episodes again instead of aggregating).
    """
    from surrol_data.datasets.guard import require_valid
    from surrol_data.datasets.output_path import new_output

    out = new_output(out)
    if not inputs:
        raise ValueError("merge needs at least one input dataset")
    resolved = [Path(r).resolve() for r in inputs]
    if out.exists():
        raise FileExistsError(f"{out} already exists: choose a new output folder"
                              + (" (it is one of the inputs)" if out.resolve() in resolved else ""))
    _refuse_out_inside(out, resolved)
    # a damaged input is refused (or a killed recording repaired) before anything is written
    read = {root: require_valid(root) for root in dict.fromkeys(resolved)}
    readers = [DatasetReader(read[root]) for root in resolved]
    shared = _check_compatible(readers)
    selection = [(reader.root, reader.select()) for reader in readers]
    kept, duplicates = _without_duplicates(readers, selection)
    if duplicates:
        if not drop_duplicates:
            twice = list(dict.fromkeys(str(p) for p in resolved if resolved.count(p) > 1))
            raise _duplicates_error("merge" + (f" ({', '.join(twice)} given more than once)" if twice else ""),
                                    duplicates)
        return copy_episodes(kept, out, operation="merge", command=command, progress=progress, drop_duplicates=True,
                             _duplicates=duplicates)
    return _aggregate(readers, out, shared, command=command if command is not None else shlex.join(sys.argv),
                      progress=progress)


STAGING_SUFFIX = ".merging"


def staging_folder(out: Path) -> Path:
    """Where a merge into ``out`` is built before it is renamed into place (hidden, beside ``out``)."""
    return out.parent / f".{out.name}{STAGING_SUFFIX}"


def _aggregate(readers: list[DatasetReader], out: Path, shared: dict, *, command: str, progress: bool) -> Path:
    """LeRobot's aggregate_datasets into a staging folder, then traces, sidecar and card, then rename to ``out``."""
    import shutil

    from surrol_data.datasets.card import write_dataset_card
    from surrol_data.datasets.hub_offline import hub_offline, lerobot_root, local_repo_id, quiet_video_encoder
    from surrol_data.datasets.lock import DatasetLock, writer_pid
    from surrol_data.datasets.schema import package_version, utc_now_iso
    from surrol_data.datasets.writer import _write_json_atomic, git_commit

    staging = staging_folder(out)
    if staging.exists():
        if writer_pid(staging) is not None:
            raise DatasetError(f"another merge into {out} is running (pid {writer_pid(staging) or '?'}); wait for it")
        shutil.rmtree(staging)  # left by a killed merge: it never became an output, nothing in it is anyone's data
    staging.mkdir(parents=True)
    built = staging / "dataset"  # a plain name for lerobot (``out``'s may hold [1] or spaces); renamed below
    started = utc_now_iso()
    try:
        with DatasetLock(staging):
            from lerobot.datasets.aggregate import aggregate_datasets

            with hub_offline(), quiet_video_encoder(), _lerobot_progress(progress):
                aggregate_datasets([local_repo_id(r.root) for r in readers], local_repo_id(out),
                                   roots=[lerobot_root(r.root) for r in readers],
                                   aggr_root=lerobot_root(staging) / built.name)
            _restore_frame_types(built, readers[0].root)
            _point_episode_rows_at_their_files(built)
            _unknown_floats_back_to_nan(built)
            provenance_of, offset = [], 0
            for reader in readers:
                for ep in reader.select():
                    provenance_of.append({"episode": offset + int(ep), "source_root": str(reader.root),
                                          "source_episode": int(ep)})
                    copy_trace(reader.root, int(ep), built, offset + int(ep))
                offset += len(reader)
            side = read_sidecar(readers[0].root)
            for stale in ("checkpoint", "sessions", "derived_from", "created_at", "seals", "signature"):
                side.pop(stale, None)
            if all(read_sidecar(r.root).get("seals") for r in readers):
                side["seals"] = 1  # every episode came with its seals (an unsealed input's episodes have none)
            info_text = (built / "meta" / "info.json").read_text()
            now = utc_now_iso()
            side.update({"repo_id": local_repo_id(out), "created_at": now, "updated_at": now,
                         "package_version": package_version(),
                         "sessions": [{"started_at": started, "ended_at": now, "command": command,
                                       "git_commit": git_commit(), "package_version": package_version(),
                                       "first_episode": 0, "episodes": offset}],
                         "checkpoint": {"at": now, "episodes": offset, "info": json.loads(info_text)},
                         "derived_from": {"operation": "merge", "where": "", "duplicates_dropped": [],
                                          "method": "lerobot.datasets.aggregate.aggregate_datasets",
                                          "sources": [{"root": str(r.root.resolve()), "episodes": len(r)}
                                                      for r in readers],
                                          "episodes": provenance_of}})
            _write_json_atomic(built / SIDECAR_PATH, side)
            write_dataset_card(built)
        (built / ".surrol_data.lock").unlink(missing_ok=True)
        built.rename(out)  # atomic: before it, no output; after it, the whole output
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out


def _restore_frame_types(root: Path, like: Path) -> None:
    """aggregate_datasets rewrites the data parquet through pandas, which turns each fixed-size vector column into
    a variable-length list and drops the Hugging Face features metadata; cast the files back to the schema the
    recorder wrote (that of ``like``'s data), keeping one row group per episode."""
    import os

    import pyarrow.parquet as pq
    from lerobot.datasets.io_utils import write_table_one_row_group_per_episode

    from surrol_data.datasets.reader import DATA_DIR, parquet_files

    schema = pq.read_schema(parquet_files(like, DATA_DIR)[0])
    for path in parquet_files(root, DATA_DIR):
        table = pq.read_table(path)
        if table.schema.equals(schema, check_metadata=True):
            continue
        table = table.select(schema.names).cast(schema).replace_schema_metadata(schema.metadata)
        tmp = path.with_name(path.name + ".tmp")
        write_table_one_row_group_per_episode(table, tmp)
        os.replace(tmp, path)


def _point_episode_rows_at_their_files(root: Path) -> None:
    """aggregate_datasets (lerobot 0.6.1) appends every episodes-metadata file of a source into one file but shifts
    each row's ``meta/episodes/chunk_index``/``file_index`` as if the files had stayed apart; a source recorded in
    several files (the recorder's checkpoints) then names files its rows are not in. Name the file each row is in."""
    import os
    import re

    import pyarrow as pa
    import pyarrow.parquet as pq

    from surrol_data.datasets.reader import EPISODES_DIR, parquet_files

    for path in parquet_files(root, EPISODES_DIR):
        chunk, file = (int(v) for v in re.findall(r"\d+", path.relative_to(root / EPISODES_DIR).as_posix())[-2:])
        table = pq.read_table(path)
        for column, value in (("meta/episodes/chunk_index", chunk), ("meta/episodes/file_index", file)):
            if column in table.column_names:
                at = table.column_names.index(column)
                typ = table.schema.field(column).type
                table = table.set_column(at, table.schema.field(column), pa.array([value] * table.num_rows, typ))
        tmp = path.with_name(path.name + ".tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, path)


def _unknown_floats_back_to_nan(root: Path) -> None:
    """aggregate_datasets passes the episodes metadata through pandas, which turns a float NaN (our "unknown", e.g.
    the ``duration_s`` of an episode whose wall time was not measured) into a null; provenance never holds a null
    (validate refuses it, and the seal was taken over the NaN). Put the NaN back in every float provenance column."""
    import os

    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    from surrol_data.datasets.reader import EPISODES_DIR, parquet_files
    from surrol_data.datasets.schema import PROVENANCE_PREFIX

    for path in parquet_files(root, EPISODES_DIR):
        table = pq.read_table(path)
        nulls = [name for name, field in zip(table.column_names, table.schema, strict=True)
                 if name.startswith(PROVENANCE_PREFIX) and pa.types.is_floating(field.type)
                 and table.column(name).null_count]
        if not nulls:
            continue
        for name in nulls:
            at = table.column_names.index(name)
            column = table.column(name)
            table = table.set_column(at, table.schema.field(name), pc.fill_null(column, pa.scalar(float("nan"),
                                                                                               column.type)))
        tmp = path.with_name(path.name + ".tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, path)


@contextlib.contextmanager
def _lerobot_progress(show: bool):
    """aggregate_datasets reports through tqdm bars of its own; silence them when our caller asked for no progress."""
    if show:
        yield
        return
    import tqdm as tqdm_module

    original = tqdm_module.tqdm

    def quiet(*args, **kwargs):
        kwargs["disable"] = True
        return original(*args, **kwargs)

    tqdm_module.tqdm = quiet
    try:
        yield
    finally:
        tqdm_module.tqdm = original


def _duplicates_error(operation: str, duplicates: list[tuple[str, str]]) -> DatasetError:
    listed = "; ".join(f"{a} = {b}" for a, b in duplicates[:5]) + (
        f" (+{len(duplicates) - 5} more)" if len(duplicates) > 5 else "")
    return DatasetError(f"{operation}: {len(duplicates)} episode(s) are exact copies of earlier ones (same "
                        f"content_hash): {listed}. Nothing was written; pass --drop-duplicates to keep one copy "
                        "of each, or leave the repeated dataset out")


def filter_dataset(src: str | Path, out: str | Path, where: str | None, *, command: str | None = None,
                   progress: bool = True, episodes: list[int] | None = None) -> Path:
    """Episodes of ``src`` matching the :mod:`~surrol_data.datasets.where` expression ``where`` (all if None) and
    listed in ``episodes`` (indices; all if None) into ``out``."""
    from surrol_data.datasets.episode_ranges import chosen_episodes
    from surrol_data.datasets.guard import require_valid

    if where is None and episodes is None:
        raise ValueError("say which episodes to keep: --where EXPRESSION and/or --episodes 0,3,5-9")
    src = require_valid(src)
    chosen = chosen_episodes(DatasetReader(src), where, episodes)
    return copy_episodes([(src, chosen)], out, operation="filter", where=where, command=command,
                         progress=progress)


def split_dataset(src: str | Path, out: str | Path, valid_fraction: float = 0.1, seed: int = 0, *,
                  where: str | None = None, command: str | None = None, progress: bool = True) -> dict[str, Path]:
    """``out/train`` and ``out/valid`` (see :func:`~surrol_data.datasets.split.split_episodes`)."""
    from surrol_data.datasets.split import split_episodes

    from surrol_data.datasets.guard import require_valid
    from surrol_data.datasets.output_path import new_output

    out = new_output(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists: choose a new output folder")

    src = require_valid(src)
    reader = DatasetReader(src)
    chosen = reader.episodes[reader.episodes["episode_index"].isin(reader.select(where))] if where \
        else reader.episodes
    train, valid = split_episodes(chosen, valid_fraction, seed)
    if not valid:
        raise DatasetError(f"{src}: --valid-fraction {valid_fraction} leaves no validation episode "
                           f"({len(chosen)} episodes); use a larger fraction or more episodes")
    parts = {}
    for name, episodes in (("train", train), ("valid", valid)):
        parts[name] = copy_episodes([(src, episodes)], out / name, operation=f"split ({name}, seed {seed})",
                                    where=where, command=command, progress=progress)
    (out / "split.json").write_text(json.dumps({"source": str(Path(src).resolve()), "seed": seed,
                                                "valid_fraction": valid_fraction, "train": train,
                                                "valid": valid}, indent=2))
    return parts

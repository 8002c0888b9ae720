"""Make new datasets out of existing ones — merge, filter, train/valid split — with provenance intact.

Every episode is read with :class:`~surrol_data.datasets.reader.DatasetReader` and written again through
:class:`~surrol_data.collect.recorder.DatasetRecorder` (the real ``lerobot`` writer) with *all* its provenance
columns given explicitly, so nothing is recomputed or lost: operator, skill, seed, the original command
line, recording time and git commit travel with the episode. Episode indices are renumbered 0..N-1 in the
output; ``meta/surrol_data.json`` records where each one came from (``derived_from``), and the card says so.

(LeRobot's own ``dataset_tools.split_dataset`` / ``delete_episodes`` rebuild the episodes table and drop
extra per-episode columns, so they cannot be used here; see shared/docs/reference/lerobot.md §2.)

Camera datasets: the reader does not decode video, so frames are decoded with ``LeRobotDataset`` and
re-encoded (lossy, like any video re-encode).
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import PROVENANCE_COLUMNS, SIDECAR_PATH

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
        theirs = _user_features(other.info)
        diff = sorted(k for k in set(features) | set(theirs)
                      if k not in features or k not in theirs
                      or (features[k]["dtype"], features[k]["shape"]) != (theirs[k]["dtype"], theirs[k]["shape"]))
        if diff:
            raise DatasetError(f"cannot combine {first.root} with {other.root}: features differ in {diff}")
        missing = [k for k in PROVENANCE_COLUMNS if k not in other.episodes.columns]
        if missing:
            raise DatasetError(f"{other.root}: episodes lack provenance column(s) {missing}")
    return {"features": features, "task": side["task"], "env_id": side["env_id"],
            "task_description": _task_description(first.root, side),
            "robot_type": first.info.get("robot_type") or "dvrk_psm"}


class _VideoFrames:
    """Decoded camera frames of one dataset (opened only when the dataset has cameras)."""

    def __init__(self, reader: DatasetReader):
        from surrol_data.collect.recorder import VIDEO_BACKEND, _lerobot_dataset_class

        self.keys = [k for k, ft in reader.features.items() if ft["dtype"] == "video"]
        from surrol_data.datasets.hub_offline import hub_offline

        with hub_offline():
            self.ds = _lerobot_dataset_class()(f"local/{reader.root.name}", root=reader.root,
                                               video_backend=VIDEO_BACKEND)

    def episode(self, ep: int) -> dict[str, np.ndarray]:
        row = self.ds.meta.episodes[int(ep)]
        frames = {k: [] for k in self.keys}
        for i in range(int(row["dataset_from_index"]), int(row["dataset_to_index"])):
            item = self.ds[i]
            for k in self.keys:
                chw = item[k].numpy()
                frames[k].append(np.clip(np.rint(chw.transpose(1, 2, 0) * 255.0), 0, 255).astype(np.uint8))
        # The recorder stores images of s_0..s_{T-1}; Trajectory wants T+1, the last is never written.
        return {k.removeprefix("observation.images."): np.stack(v + v[-1:]) for k, v in frames.items()}


def copy_episodes(selection: list[tuple[str | Path, list[int]]], out: str | Path, *, operation: str,
                  where: str | None = None, command: str | None = None, progress: bool = True,
                  drop_duplicates: bool = False) -> Path:
    """Write the episodes ``selection`` = [(dataset root, [episode indices]) ...] into a new dataset ``out``.

    Inputs must share the task, env id and frame features, and pass the cheap validation checks. An episode
    whose content hash equals an earlier one's is refused (DatasetError), or skipped with ``drop_duplicates``.
    Returns ``out``.
    """
    from surrol_data.collect.recorder import DatasetRecorder, _write_json_atomic
    from surrol_data.datasets.card import write_dataset_card

    from surrol_data.datasets.guard import require_valid

    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists: choose a new output folder")
    for root in dict.fromkeys(Path(r).resolve() for r, _ in selection):
        require_valid(root)  # cheap checks: a damaged input is refused before anything is written
    readers = [DatasetReader(root) for root, _ in selection]
    for reader, (_, episodes) in zip(readers, selection, strict=True):
        for ep in episodes:
            reader._episode_row(ep)  # DatasetError naming a missing episode, before anything is written
        if reader.root.resolve() == out.resolve():
            raise ValueError(f"the output {out} is one of the inputs")
    shared = _check_compatible(readers)
    selection, duplicates = _without_duplicates(readers, selection)
    if duplicates and not drop_duplicates:
        listed = "; ".join(f"{a} = {b}" for a, b in duplicates[:5]) + (
            f" (+{len(duplicates) - 5} more)" if len(duplicates) > 5 else "")
        raise DatasetError(f"{operation}: {len(duplicates)} episode(s) are exact copies of earlier ones (same "
                           f"content_hash): {listed}. Nothing was written; pass --drop-duplicates to keep one copy "
                           "of each, or leave the repeated dataset out")
    total = sum(len(eps) for _, eps in selection)
    if total == 0:
        raise DatasetError(f"{operation}: no episode selected" + (f" by --where {where!r}" if where else "")
                           + "; nothing to write")
    command = command if command is not None else shlex.join(sys.argv)
    provenance_of = []
    recorder = DatasetRecorder(out, features=shared["features"], task=shared["task"], env_id=shared["env_id"],
                               task_description=shared["task_description"], robot_type=shared["robot_type"],
                               command=command, checkpoint_every=50)
    bar = tqdm(total=total, desc=f"{operation} -> {out.name}", unit="ep", disable=not progress)
    try:
        with recorder:
            for reader, (_, episodes) in zip(readers, selection, strict=True):
                has_video = any(ft["dtype"] == "video" for ft in reader.features.values())
                video = _VideoFrames(reader) if has_video else None
                rows = reader.episodes.set_index("episode_index")
                for ep in episodes:
                    traj = reader.trajectory(ep)
                    if video is not None:
                        traj.images = video.episode(ep)
                    prov = {k: _plain(rows.at[int(ep), k]) for k in PROVENANCE_COLUMNS}
                    new_index = recorder.record(traj, prov)
                    provenance_of.append({"episode": new_index, "source_root": str(reader.root), "source_episode": int(ep)})
                    bar.update(1)
    finally:
        bar.close()
    side = read_sidecar(out)
    side["derived_from"] = {"operation": operation, "where": where or "",
                            "duplicates_dropped": [{"episode": b, "copy_of": a} for a, b in duplicates],
                            "sources": [{"root": str(r.root.resolve()), "episodes": len(eps)}
                                        for r, (_, eps) in zip(readers, selection, strict=True)],
                            "episodes": provenance_of}
    _write_json_atomic(out / SIDECAR_PATH, side)
    write_dataset_card(out)
    return out


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
    """All episodes of ``inputs``, in order, into the new dataset ``out`` (duplicates refused unless dropped)."""
    from surrol_data.datasets.guard import require_valid

    if not inputs:
        raise ValueError("merge needs at least one input dataset")
    for root in dict.fromkeys(Path(r).resolve() for r in inputs):
        require_valid(root)
    selection = [(root, DatasetReader(root).select()) for root in inputs]
    return copy_episodes(selection, out, operation="merge", command=command, progress=progress,
                         drop_duplicates=drop_duplicates)


def filter_dataset(src: str | Path, out: str | Path, where: str, *, command: str | None = None,
                   progress: bool = True) -> Path:
    """Episodes of ``src`` matching the :mod:`~surrol_data.datasets.where` expression ``where`` into ``out``."""
    from surrol_data.datasets.guard import require_valid

    require_valid(src)
    episodes = DatasetReader(src).select(where)
    return copy_episodes([(src, episodes)], out, operation="filter", where=where, command=command,
                         progress=progress)


def split_dataset(src: str | Path, out: str | Path, valid_fraction: float = 0.1, seed: int = 0, *,
                  where: str | None = None, command: str | None = None, progress: bool = True) -> dict[str, Path]:
    """``out/train`` and ``out/valid`` (see :func:`~surrol_data.datasets.split.split_episodes`)."""
    from surrol_data.datasets.split import split_episodes

    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists: choose a new output folder")
    from surrol_data.datasets.guard import require_valid

    require_valid(src)
    reader = DatasetReader(src)
    chosen = reader.episodes[reader.episodes["episode_index"].isin(reader.select(where))] if where \
        else reader.episodes
    train, valid = split_episodes(chosen, valid_fraction, seed)
    if not valid:
        raise DatasetError(f"{src}: valid_fraction={valid_fraction} leaves no validation episode "
                           f"({len(chosen)} episodes); use a larger fraction or more episodes")
    parts = {}
    for name, episodes in (("train", train), ("valid", valid)):
        parts[name] = copy_episodes([(src, episodes)], out / name, operation=f"split ({name}, seed {seed})",
                                    where=where, command=command, progress=progress)
    (out / "split.json").write_text(json.dumps({"source": str(Path(src).resolve()), "seed": seed,
                                                "valid_fraction": valid_fraction, "train": train,
                                                "valid": valid}, indent=2))
    return parts

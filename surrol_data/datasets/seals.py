"""Which episodes no longer match the seals recorded with them (see :func:`surrol_data.datasets.schema.provenance_seal`).

``validate`` (and so every command that checks its input first) reports what these functions find, naming the
episodes: a provenance value edited in ``meta/episodes`` (operator ``e1`` → ``e2``, ``expert`` → ``novice``)
breaks ``seal/provenance``; another recording's mp4 copied over a video file breaks ``seal/<video key>`` of every
episode whose segment it holds. A device trace is a second, independent record of a haptic episode: its own
metadata (task, seed, operator, skill, device) must say what the episode's provenance says.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pyarrow as pa

from surrol_data.datasets.schema import (
    FPS,
    PROVENANCE_COLUMNS,
    PROVENANCE_PREFIX,
    PROVENANCE_SEAL,
    provenance_seal,
    video_seal_column,
)

# Trace metadata key -> the provenance column it must equal (collect.haptic_source writes both).
TRACE_FIELDS = ("task", "env_id", "seed", "operator_id", "skill", "operator_simulated", "operator_params")


def video_segment(video_path: str, key: str, row: Mapping) -> tuple[str, float, float] | None:
    """(file relative to the dataset, from, to seconds) of one episode's segment of video ``key``: ``row`` holds its
    ``meta/episodes`` values, ``video_path`` is info.json's template. None when the row does not place it."""
    chunk, file, start, end = (row.get(f"videos/{key}/{c}")
                               for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp"))
    if chunk is None or file is None or start is None or end is None:
        return None
    return video_path.format(video_key=key, chunk_index=chunk, file_index=file), float(start), float(end)


def segment_seal(root: Path, video_path: str, key: str, row: Mapping) -> str:
    """The seal of one episode's segment of video ``key`` (see :func:`video_segment`): the digest of its packets."""
    from surrol_data.datasets.video import segment_digest

    rel, start, end = video_segment(video_path, key, row)
    return segment_digest(Path(root) / rel, start, end, FPS)


def provenance_mismatches(meta: pa.Table, sealed: bool) -> tuple[list[int], list[int]]:
    """(episodes whose provenance differs from their seal, episodes without a seal although ``sealed``)."""
    if any(PROVENANCE_PREFIX + name not in meta.column_names for name in PROVENANCE_COLUMNS):
        return [], []  # the provenance check reports the missing column
    episodes = meta.column("episode_index").to_pylist()
    if PROVENANCE_SEAL not in meta.column_names:
        return [], (list(episodes) if sealed else [])
    columns = {name: meta.column(PROVENANCE_PREFIX + name).to_pylist() for name in PROVENANCE_COLUMNS}
    seals = meta.column(PROVENANCE_SEAL).to_pylist()
    bad, missing = [], []
    for row, ep in enumerate(episodes):
        if seals[row] is None:
            if sealed:
                missing.append(int(ep))
            continue
        if provenance_seal({name: values[row] for name, values in columns.items()}) != seals[row]:
            bad.append(int(ep))
    return bad, missing


def video_mismatches(root: Path, info: dict, meta: pa.Table, sealed: bool) -> dict[str, tuple[list[int], list[int]]]:
    """Per video file: (episodes whose segment differs from their seal, episodes without a seal although ``sealed``).
    Files that cannot be read are left to the videos check (it names them)."""
    from surrol_data.datasets.errors import DatasetError
    from surrol_data.datasets.video import segment_digest

    found: dict[str, tuple[list[int], list[int]]] = {}
    keys = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
    for key in keys:
        column = video_seal_column(key)
        seals = meta.column(column).to_pylist() if column in meta.column_names else [None] * meta.num_rows
        cols = [f"videos/{key}/{c}" for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")]
        if any(c not in meta.column_names for c in cols):
            continue
        for row, seal in zip(meta.select(["episode_index", *cols]).to_pylist(), seals, strict=True):
            segment = video_segment(info["video_path"], key, row)
            if segment is None:
                continue
            rel, start, end = segment
            bad, missing = found.setdefault(rel, ([], []))
            if seal is None:
                if sealed:
                    missing.append(int(row["episode_index"]))
                continue
            try:
                if segment_digest(root / rel, start, end, FPS) != seal:
                    bad.append(int(row["episode_index"]))
            except DatasetError:
                continue
    return {rel: v for rel, v in found.items() if v[0] or v[1]}


def trace_disagreements(trace_meta: dict, provenance: dict) -> list[str]:
    """``"name: trace X, provenance Y"`` for each field in which a device trace's metadata contradicts the
    provenance of its episode (fields a trace does not hold are not compared)."""
    out = []
    for name in TRACE_FIELDS:
        if name in trace_meta and name in provenance and trace_meta[name] != provenance[name]:
            out.append(f"{name}: trace {trace_meta[name]!r}, provenance {provenance[name]!r}")
    devices = trace_meta.get("devices")
    if isinstance(devices, list) and devices and "device" in provenance and devices[0] != provenance["device"]:
        out.append(f"device: trace {devices[0]!r}, provenance {provenance['device']!r}")
    return out

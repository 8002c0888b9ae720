"""Device traces: the raw device frames of a haptic episode, saved next to the dataset so it can be replayed.

Every kept episode of a haptic session gets ``<dataset>/meta/device_traces/episode_XXXXXX.npz`` holding

* ``frames``: float64 (n_devices, T, 8) — one :meth:`DeviceFrame.to_row` per env step and device (the
  session reads each device exactly once per step, so frame k produced action k);
* ``actions``: float32 (T, act_dim) — the actions the env executed (a replay checks itself against them);
* ``meta``: JSON text — format version, task, env id, seed, horizon, device names and sides, the mapping
  settings of each device, and the operator fields of the episode's provenance.

With the same env seed, the same frames and the same mapping settings, the mapping and the env are
deterministic, so :class:`surrol_data.collect.devices.replay.ReplayDevice` reproduces the episode exactly.
Files are written atomically (a kill never leaves half a trace).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from surrol_data.collect.devices.base import DeviceError, DeviceFrame
from surrol_data.collect.mapping import MappingSettings

TRACE_DIR = "meta/device_traces"
TRACE_FORMAT = 1
_ROW = 8  # x, y, z, g0, g1, g2, buttons, t


@dataclass
class DeviceTrace:
    """One episode's device frames and what is needed to replay them."""
    frames: np.ndarray        # (n_devices, T, 8)
    actions: np.ndarray       # (T, act_dim)
    meta: dict

    @property
    def seed(self) -> int:
        return int(self.meta["seed"])

    @property
    def n_devices(self) -> int:
        return int(self.frames.shape[0])

    def __len__(self) -> int:
        return int(self.frames.shape[1])

    def device_frames(self, device: int) -> list[DeviceFrame]:
        return [DeviceFrame.from_row(row) for row in self.frames[device]]

    def mapping(self, device: int) -> MappingSettings:
        return mapping_from_dict(self.meta["mapping"][device])


def trace_path(dataset_root: str | Path, episode_index: int) -> Path:
    return Path(dataset_root) / TRACE_DIR / f"episode_{int(episode_index):06d}.npz"


def mapping_from_dict(d: dict) -> MappingSettings:
    """Inverse of :meth:`MappingSettings.as_dict` (JSON turns tuples into lists)."""
    fields = MappingSettings.__dataclass_fields__
    unknown = sorted(set(d) - set(fields))
    if unknown:
        raise ValueError(f"unknown mapping setting(s) {unknown}; known: {sorted(fields)}")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    # Traces written before the camera frame existed name no frame: their mapping was the robot frame's.
    values.setdefault("frame", "robot")
    return MappingSettings(**values)


def write_trace(path: str | Path, frames: list[list[DeviceFrame]], actions, meta: dict) -> Path:
    """Save one episode's frames (one list per device, all of length T) and executed actions."""
    lengths = {len(f) for f in frames}
    if len(lengths) != 1:
        raise ValueError(f"every device needs one frame per step; got frame counts {sorted(lengths)}")
    rows = np.asarray([[fr.to_row() for fr in dev] for dev in frames], dtype=np.float64)
    actions = np.asarray(actions, dtype=np.float32)
    if rows.shape[1] != len(actions):
        raise ValueError(f"trace has {rows.shape[1]} frames per device but {len(actions)} actions")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, frames=rows.reshape(len(frames), -1, _ROW), actions=actions,
                            meta=np.asarray(json.dumps({"format": TRACE_FORMAT, **meta}, sort_keys=True)))
    os.replace(tmp, path)
    return path


def read_trace(path: str | Path) -> DeviceTrace:
    path = Path(path)
    if not path.is_file():
        raise DeviceError(f"device trace {path} does not exist; haptic sessions save them under "
                          f"<dataset>/{TRACE_DIR}/episode_XXXXXX.npz")
    try:
        with np.load(path, allow_pickle=False) as z:
            frames, actions, meta = z["frames"], z["actions"], json.loads(str(z["meta"]))
    except (OSError, ValueError, KeyError) as e:
        raise DeviceError(f"{path} is not a readable device trace ({e}); expected an .npz written by a "
                          "haptic session") from None
    if meta.get("format") != TRACE_FORMAT or frames.ndim != 3 or frames.shape[2] != _ROW:
        raise DeviceError(f"{path}: unsupported trace (format {meta.get('format')!r}, frames {frames.shape}); "
                          f"this version reads format {TRACE_FORMAT} with (devices, T, {_ROW}) frames")
    return DeviceTrace(frames=frames, actions=actions, meta=meta)


def trace_files(path: str | Path) -> list[Path]:
    """A trace file, or every ``episode_*.npz`` of a folder (a dataset root or its trace folder), in order."""
    path = Path(path)
    if path.is_file():
        return [path]
    for folder in (path / TRACE_DIR, path):
        files = sorted(folder.glob("episode_*.npz")) if folder.is_dir() else []
        if files:
            return files
    raise DeviceError(f"no device traces at {path}: give a trace .npz, a dataset recorded by a haptic session, "
                      f"or its {TRACE_DIR} folder")

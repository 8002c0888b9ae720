"""A catalogue of ways a dataset on disk can be damaged, to prove that ``validate`` notices every one.

Each class is a function ``damage(root)`` that changes one thing in a *copy* of a good dataset — a file cut
short, deleted or swapped, a value made NaN, scaled or out of range, metadata that disagrees with the
data — covering every file of the format, every frame feature, the provenance columns, videos and device
traces. :func:`base_dataset` writes the good dataset they start from (camera video, device traces, two
data files). Used by ``tests/test_crash_safety.py`` and ``benchmarks/crash_safety.py``. It sits with the
collectors, not with the format it damages, because its good dataset carries device traces, which the haptic
collector's :mod:`~surrol_data.collect.devices.trace` writes (``docs/architecture.md``).
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

from surrol_data.datasets.schema import SIDECAR_PATH, frame_features
from surrol_data.datasets.trajectory import Trajectory

OBS, GOAL, CAMERA = 7, 3, (32, 32)
EPISODES, STEPS = 4, 6
TRACE_DIR = "meta/device_traces"
FLOAT_FEATURES = ("observation.state", "observation.environment_state", "action",
                  "next.reward", "next.observation.state", "next.observation.environment_state",
                  "complementary_info.tip_position", "complementary_info.jaw_angle",
                  "complementary_info.next_tip_position", "complementary_info.next_jaw_angle")


def _trajectory(seed: int, steps: int, camera: bool) -> Trajectory:
    rng = np.random.default_rng(seed)
    success = np.arange(steps) >= steps // 2
    h, w = CAMERA
    return Trajectory(
        observation=rng.standard_normal((steps + 1, OBS)).astype(np.float32),
        achieved_goal=rng.standard_normal((steps + 1, GOAL)).astype(np.float32),
        desired_goal=rng.standard_normal((steps + 1, GOAL)).astype(np.float32),
        action=rng.uniform(-1, 1, (steps, 5)).astype(np.float32),
        reward=success.astype(np.float32) - 1.0, success=success, terminated=np.zeros(steps, bool),
        tip_position=(0.01 * rng.standard_normal((steps + 1, 1, 3))).astype(np.float32),
        jaw_angle=rng.uniform(0, 1, (steps + 1, 1)).astype(np.float32),
        flags={"clutch": rng.random(steps) > 0.6, "jaw_button": rng.random(steps) > 0.5},
        images={"front": rng.integers(0, 255, (steps + 1, h, w, 3), dtype=np.uint8)} if camera else {})


def base_dataset(root: str | Path, camera: bool = True) -> Path:
    """A good dataset: EPISODES haptic-provenance episodes in two data files, device traces, optional video."""
    from surrol_data.collect.devices.base import DeviceFrame
    from surrol_data.collect.devices.trace import trace_path, write_trace
    from surrol_data.datasets.recorder import DatasetRecorder

    root = Path(root)
    features = frame_features(OBS, GOAL, 5, 1, cameras={"front": CAMERA} if camera else None)
    with DatasetRecorder(root, features=features, task="NeedleReach", env_id="SurRoL/NeedleReach-v0",
                         task_description="reach the needle", checkpoint_every=2, handle_signals=False,
                         consolidate=False) as rec:   # several files, as a killed or appended recording leaves
        for i in range(EPISODES):
            traj = _trajectory(i, STEPS + i, camera)
            index = rec.record(traj, {"source": "haptic", "device": "touch", "skill": "expert", "seed": i,
                                      "operator_id": "e1"})
            frames = [[DeviceFrame(np.full(3, t, float), np.zeros(3), 0, t / 5) for t in range(len(traj))]]
            # the fields a haptic session's trace holds besides the frames (validate compares them with provenance)
            write_trace(trace_path(root, index), frames, traj.action,
                        {"episode_index": index, "task": "NeedleReach", "seed": i, "operator_id": "e1",
                         "skill": "expert", "devices": ["touch"]})
    return root


# ---------------------------------------------------------------------- editing helpers

def _files(root: Path, sub: str) -> list[Path]:
    return sorted((root / sub).glob("chunk-*/file-*.parquet"))


def _truncate(path: Path) -> None:
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])


def _swap(a: Path, b: Path) -> None:
    tmp = a.with_name(a.name + ".swap")
    a.rename(tmp)
    b.rename(a)
    tmp.rename(b)


def _edit_json(path: Path, change: Callable[[dict], None]) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _write_like(table: pa.Table, path: Path) -> None:
    """Rewrite a data/meta file keeping one row group per episode (LeRobot's layout)."""
    episodes = table.column("episode_index").to_numpy()
    with pq.ParquetWriter(path, table.schema) as writer:
        for ep in np.unique(episodes):
            idx = np.flatnonzero(episodes == ep)
            writer.write_table(table.slice(int(idx[0]), len(idx)))


def _set_column(table: pa.Table, name: str, array: pa.Array) -> pa.Table:
    i = table.schema.get_field_index(name)
    return table.set_column(i, table.schema.field(name), array)


def _edit_data(root: Path, column: str, change: Callable[[np.ndarray], np.ndarray], file: int = 0) -> None:
    """Apply ``change`` to the (rows, dim) values of a data column in data file ``file``."""
    path = _files(root, "data")[file]
    table = pq.read_table(path)
    col = table.column(column).combine_chunks()
    if pa.types.is_fixed_size_list(col.type):
        values = col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), col.type.list_size).copy()
        new = pa.FixedSizeListArray.from_arrays(pa.array(change(values).reshape(-1), col.type.value_type),
                                                col.type.list_size)
    else:
        new = pa.array(change(col.to_numpy(zero_copy_only=False).copy()), col.type)
    _write_like(_set_column(table, column, new), path)


def _edit_meta(root: Path, change: Callable[[pa.Table], pa.Table], file: int = 0) -> None:
    path = _files(root, "meta/episodes")[file]
    pq.write_table(change(pq.read_table(path)), path)


def _meta_value(root: Path, column: str, value, row: int = 0) -> None:
    def change(table: pa.Table) -> pa.Table:
        values = table.column(column).to_pylist()
        values[row] = value
        return _set_column(table, column, pa.array(values, table.schema.field(column).type))

    _edit_meta(root, change)


def _nan(values: np.ndarray) -> np.ndarray:
    values.reshape(len(values), -1)[1, 0] = np.nan
    return values


def _drop_last_row(root: Path) -> None:
    path = _files(root, "data")[0]
    table = pq.read_table(path)
    _write_like(table.slice(0, table.num_rows - 1), path)


def _trace(root: Path, ep: int) -> Path:
    return root / TRACE_DIR / f"episode_{ep:06d}.npz"


def _video(root: Path) -> Path:
    return sorted((root / "videos").rglob("*.mp4"))[0]


def _journal_leftover(root: Path) -> None:
    from surrol_data.datasets import journal

    journal.write_entry(root, EPISODES, _trajectory(99, STEPS, False), {"source": "haptic"})


def _session_never_ended(root: Path) -> None:
    _edit_json(root / SIDECAR_PATH, lambda d: d["sessions"][-1].pop("ended_at"))


def _duplicate_hash(root: Path) -> None:
    first = pq.read_table(_files(root, "meta/episodes")[0]).column("provenance/content_hash").to_pylist()[0]
    _meta_value(root, "provenance/content_hash", first, row=1)


def _flip_bool(values: np.ndarray) -> np.ndarray:
    values[0] = ~values[0]
    return values


def _scale(factor: float):
    def change(values: np.ndarray) -> np.ndarray:
        return values * factor
    return change


def _stat(root: Path, feature: str, stat: str, delta: float) -> None:
    _edit_json(root / "meta" / "stats.json", lambda d: d[feature].__setitem__(stat, (np.asarray(d[feature][stat])
                                                                                     + delta).tolist()))


# ---------------------------------------------------------------------- the catalogue

CLASSES: dict[str, Callable[[Path], None]] = {
    # files of the format
    "data file truncated": lambda r: _truncate(_files(r, "data")[0]),
    "data file deleted": lambda r: _files(r, "data")[1].unlink(),
    "data file emptied": lambda r: _files(r, "data")[0].write_bytes(b""),
    "data files swapped": lambda r: _swap(*_files(r, "data")[:2]),
    "stray garbage data file": lambda r: (r / "data/chunk-000/file-009.parquet").write_bytes(b"PAR1 not parquet"),
    "data file rows lost": _drop_last_row,
    "episodes metadata truncated": lambda r: _truncate(_files(r, "meta/episodes")[0]),
    "episodes metadata deleted": lambda r: _files(r, "meta/episodes")[1].unlink(),
    "episodes metadata files swapped": lambda r: _swap(*_files(r, "meta/episodes")[:2]),
    "info.json deleted": lambda r: (r / "meta/info.json").unlink(),
    "info.json truncated": lambda r: _truncate(r / "meta/info.json"),
    "info.json not an object": lambda r: (r / "meta/info.json").write_text("[]"),
    "stats.json deleted": lambda r: (r / "meta/stats.json").unlink(),
    "stats.json truncated": lambda r: _truncate(r / "meta/stats.json"),
    "tasks.parquet deleted": lambda r: (r / "meta/tasks.parquet").unlink(),
    "tasks.parquet truncated": lambda r: _truncate(r / "meta/tasks.parquet"),
    "sidecar deleted": lambda r: (r / SIDECAR_PATH).unlink(),
    "sidecar truncated": lambda r: _truncate(r / SIDECAR_PATH),
    "unreplayed journal entry": _journal_leftover,
    "recording session never ended": _session_never_ended,
    # videos
    "video truncated": lambda r: _truncate(_video(r)),
    "video deleted": lambda r: _video(r).unlink(),
    "video segment timestamps altered": lambda r: _meta_value(r, "videos/observation.images.front/to_timestamp", 99.0),
    # device traces
    "trace deleted": lambda r: _trace(r, 1).unlink(),
    "trace truncated": lambda r: _truncate(_trace(r, 1)),
    "traces swapped": lambda r: _swap(_trace(r, 0), _trace(r, 1)),
    "orphan trace": lambda r: shutil.copy(_trace(r, 0), _trace(r, 42)),
    # info.json
    "fps changed": lambda r: _edit_json(r / "meta/info.json", lambda d: d.__setitem__("fps", 30)),
    "total_episodes wrong": lambda r: _edit_json(r / "meta/info.json", lambda d: d.__setitem__("total_episodes", 9)),
    "total_frames wrong": lambda r: _edit_json(r / "meta/info.json", lambda d: d.__setitem__("total_frames", 1)),
    "total_tasks wrong": lambda r: _edit_json(r / "meta/info.json", lambda d: d.__setitem__("total_tasks", 3)),
    "feature shape changed": lambda r: _edit_json(r / "meta/info.json",
                                                  lambda d: d["features"]["action"].__setitem__("shape", [6])),
    "feature dtype changed": lambda r: _edit_json(r / "meta/info.json",
                                                  lambda d: d["features"]["next.done"].__setitem__("dtype", "float32")),
    "feature removed": lambda r: _edit_json(r / "meta/info.json", lambda d: d["features"].pop("next.success")),
    "codebase_version changed": lambda r: _edit_json(r / "meta/info.json",
                                                     lambda d: d.__setitem__("codebase_version", "v2.1")),
    "data_path removed": lambda r: _edit_json(r / "meta/info.json", lambda d: d.pop("data_path")),
    # meta/episodes bookkeeping and statistics
    "episode length altered": lambda r: _meta_value(r, "length", 3),
    "dataset_from_index altered": lambda r: _meta_value(r, "dataset_from_index", 2, row=1),
    "data file_index points elsewhere": lambda r: _meta_value(r, "data/file_index", 1),
    "episode_index repeated": lambda r: _meta_value(r, "episode_index", 0, row=1),
    "per-episode stats altered": lambda r: _meta_value(r, "stats/action/mean", [0.9] * 5),
    "stats.json mean altered": lambda r: _stat(r, "action", "mean", 0.5),
    "stats.json max altered": lambda r: _stat(r, "observation.state", "max", 3.0),
    "episode task not in tasks.parquet": lambda r: _meta_value(r, "tasks", ["something else"]),
    # provenance columns
    "provenance null": lambda r: _meta_value(r, "provenance/operator_id", None),
    "provenance value not allowed": lambda r: _meta_value(r, "provenance/skill", "guru"),
    "provenance wrong type": lambda r: _edit_meta(r, lambda t: t.set_column(
        t.schema.get_field_index("provenance/seed"), pa.field("provenance/seed", pa.string()),
        pc.cast(t.column("provenance/seed"), pa.string()))),
    "provenance column removed": lambda r: _edit_meta(r, lambda t: t.drop_columns(["provenance/device"])),
    "provenance JSON broken": lambda r: _meta_value(r, "provenance/device_settings", "{"),
    "provenance episode_steps wrong": lambda r: _meta_value(r, "provenance/episode_steps", 2),
    "provenance success flipped": lambda r: _meta_value(r, "provenance/success", False, row=1),
    "provenance path length altered": lambda r: _meta_value(r, "provenance/path_length_cm", 123.0),
    "provenance jaw closures altered": lambda r: _meta_value(r, "provenance/jaw_closures", 40),
    "provenance clutch uses altered": lambda r: _meta_value(r, "provenance/clutch_uses", 40),
    "provenance content hash altered": lambda r: _meta_value(r, "provenance/content_hash", "0" * 32),
    "provenance task differs from sidecar": lambda r: _meta_value(r, "provenance/task", "PegTransfer"),
    "sidecar env id changed": lambda r: _edit_json(r / SIDECAR_PATH, lambda d: d.__setitem__("env_id", "SurRoL/X-v0")),
    "duplicate episode": _duplicate_hash,
    # frame values
    **{f"NaN in {name}": (lambda name: lambda r: _edit_data(r, name, _nan))(name) for name in FLOAT_FEATURES},
    "inf in action": lambda r: _edit_data(r, "action", lambda v: np.where(np.arange(v.size).reshape(v.shape) == 0,
                                                                          np.inf, v)),
    "actions x100": lambda r: _edit_data(r, "action", _scale(100.0)),
    "observations x10": lambda r: (_edit_data(r, "observation.state", _scale(10.0)),
                                   _edit_data(r, "next.observation.state", _scale(10.0))),
    "reward altered": lambda r: _edit_data(r, "next.reward", lambda v: v + 0.5),
    "done flipped": lambda r: _edit_data(r, "next.done", _flip_bool),
    "success flipped": lambda r: _edit_data(r, "next.success", _flip_bool),
    "clutch flag flipped": lambda r: _edit_data(r, "complementary_info.clutch", _flip_bool),
    "jaw button flag flipped": lambda r: _edit_data(r, "complementary_info.jaw_button", _flip_bool),
    "frame_index shuffled": lambda r: _edit_data(r, "frame_index", lambda v: v[::-1].copy()),
    "episode_index changed in data": lambda r: _edit_data(r, "episode_index", lambda v: np.where(v == 0, 1, v)),
    "global index altered": lambda r: _edit_data(r, "index", lambda v: v + 3),
    "timestamp altered": lambda r: _edit_data(r, "timestamp", lambda v: v * 2),
    "task_index out of range": lambda r: _edit_data(r, "task_index", lambda v: v + 5),
    "next state chain broken": lambda r: _edit_data(r, "next.observation.state",
                                                    lambda v: v + (np.arange(len(v)) == 2)[:, None]),
}


def damaged_copy(base: Path, name: str, out: Path) -> Path:
    """A copy of ``base`` at ``out`` with damage ``name`` applied."""
    shutil.copytree(base, out)
    CLASSES[name](out)
    return out

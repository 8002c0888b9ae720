"""Fast numpy reading of a surrol_data LeRobot v3 dataset, straight from its parquet files.

No ``lerobot`` import (it costs ~6 s and ~0.9 GB): the layout is read with pyarrow. LeRobot writes one
row group per episode, so one episode is one row-group read (~0.5 ms); :meth:`DatasetReader.transitions`
reads the whole dataset in one pass. Camera frames are decoded on request (:meth:`DatasetReader.frames`,
``trajectory(ep, images=True)``) with PyAV (:mod:`surrol_data.datasets.video`).

What each column holds is fixed by :mod:`surrol_data.datasets.schema`.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from surrol_data.datasets.errors import DatasetError
from surrol_data.datasets.schema import (
    ENV_STATE,
    INTERVENTION_ARMS,
    INTERVENTION_FEATURES,
    NEXT_ENV_STATE,
    POLICY_ACTION,
    PROVENANCE_PREFIX,
    is_schema1,
    split_environment_state,
)
from surrol_data.datasets.trajectory import DEVICE_FLAGS, EVENT_FLAGS, INTERVENTION, Trajectory

INFO_PATH = "meta/info.json"
CODEBASE_VERSION = "v3.0"  # the only LeRobot format read: what lerobot 0.6 writes (v3.1 or "v30" are not it)
EPISODES_DIR = "meta/episodes"
DATA_DIR = "data"

# Frame columns the reader needs to rebuild a Trajectory / transitions (the goals are the two halves of the
# environment state).
_TRANSITION_COLUMNS = {
    "obs": "observation.state",
    "environment_state": ENV_STATE,
    "action": "action",
    "reward": "next.reward",
    "next_obs": "next.observation.state",
    "next_environment_state": NEXT_ENV_STATE,
    "done": "next.done",
    "success": "next.success",
}
_SCALAR_KEYS = ("reward", "done", "success")
_GOAL_SPLIT = {"environment_state": ("achieved_goal", "desired_goal"),
               "next_environment_state": ("next_achieved_goal", "next_desired_goal")}
_TRAJECTORY_EXTRA = ("complementary_info.tip_position", "complementary_info.jaw_angle",
                     "complementary_info.next_tip_position", "complementary_info.next_jaw_angle",
                     *(f"complementary_info.{f}" for f in DEVICE_FLAGS))


def parquet_files(root: Path, subdir: str) -> list[Path]:
    """``<root>/<subdir>/chunk-*/file-*.parquet`` in LeRobot's order."""
    return sorted((Path(root) / subdir).glob("chunk-*/file-*.parquet"))


def unreadable_parquet_files(root: str | Path) -> list[Path]:
    """Data / episode-metadata parquet files without a valid footer (a recorder killed before finalize)."""
    bad = []
    for sub in (DATA_DIR, EPISODES_DIR):
        for path in parquet_files(Path(root), sub):
            try:
                pq.read_metadata(path)
            except (pa.ArrowInvalid, OSError):
                bad.append(path)
    return bad


def load_info(root: str | Path) -> dict:
    """``meta/info.json`` of a LeRobot v3 dataset, or :class:`DatasetError` saying what was expected."""
    root = Path(root)
    if not root.exists():
        raise DatasetError(f"{root} does not exist: expected a LeRobot v3 dataset folder "
                           "(with meta/info.json, meta/episodes/ and data/)")
    if not root.is_dir():
        raise DatasetError(f"{root} is a file: expected a LeRobot v3 dataset folder")
    path = root / INFO_PATH
    if not path.exists():
        raise DatasetError(f"{root} is not a LeRobot dataset: {INFO_PATH} is missing "
                           "(expected meta/info.json, meta/episodes/ and data/; is this the dataset root?)")
    try:
        info = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path} is not valid JSON ({e}); the recording was probably killed while writing it: "
                           f"run `surrol-data repair {root}`") from None
    if not isinstance(info, dict):
        raise DatasetError(f"{path} holds a JSON {type(info).__name__}, not LeRobot's info object; restore it or "
                           "run `surrol-data repair` (it rewrites info.json from the recorder's saved copy)")
    version = str(info.get("codebase_version", ""))
    if version != CODEBASE_VERSION:
        if re.fullmatch(r"v[12](\.\d+)*", version):
            raise DatasetError(f"{root} is a LeRobot dataset of codebase_version {version!r}; expected "
                               f"{CODEBASE_VERSION!r} (convert it with lerobot's convert_dataset_v21_to_v30)")
        raise DatasetError(f"{root}: meta/info.json says codebase_version {version!r}; surrol_data reads "
                           f"{CODEBASE_VERSION!r}, the format lerobot 0.6 writes (a newer or unknown format: read it "
                           "with the lerobot that wrote it, or restore info.json if it was edited)")
    return info


_EPISODE_ROWS: dict[tuple[str, int, int], pa.Table] = {}


def episode_rows(path: Path) -> pa.Table:
    """The rows of one ``meta/episodes`` file without its per-episode statistics (``stats/*``), remembered for this
    process by the file's path, size and modification time: most of the cost of reading one is parsing its footer
    (~230 column descriptions, ~4 ms), and a command reads each file twice — its input check, then its reader.
    Raises what pyarrow raises on a damaged file."""
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _EPISODE_ROWS:
        pf = pq.ParquetFile(path)
        if len(_EPISODE_ROWS) > 20_000:
            _EPISODE_ROWS.clear()
        _EPISODE_ROWS[key] = pf.read(columns=[n for n in pf.schema_arrow.names if not n.startswith("stats/")])
    return _EPISODE_ROWS[key]


def _check_readable(root: Path, bad: list[Path] | None = None) -> None:
    bad = unreadable_parquet_files(root) if bad is None else bad
    if bad:
        names = ", ".join(str(p.relative_to(root)) for p in bad)
        raise DatasetError(f"{root}: {names} cannot be read (no parquet footer: the recorder was killed before it "
                           f"could finalize). Run `surrol-data repair {root}` to keep every episode "
                           "completed before the last checkpoint.")


def column_to_numpy(column: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """(N, dim) array of a fixed/variable-size list column, (N,) of a scalar column."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    if pa.types.is_fixed_size_list(arr.type):
        # flatten() honours slice offsets, unlike .values
        return arr.flatten().to_numpy(zero_copy_only=False).reshape(len(arr), arr.type.list_size)
    if pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type):
        flat = arr.flatten().to_numpy(zero_copy_only=False)
        return flat.reshape(len(arr), -1) if len(arr) else flat.reshape(0, 0)
    return arr.to_numpy(zero_copy_only=False)


def _as_2d(values: np.ndarray, dim: int) -> np.ndarray:
    return values.reshape(len(values), dim)


def trajectory_from_table(table: pa.Table, features: dict) -> Trajectory:
    """The :class:`Trajectory` of one episode's frame rows (in frame order), ``features`` from info.json."""
    arrays = {name: column_to_numpy(table.column(name)) for name in table.column_names}

    def dim(key: str) -> int:
        return int(np.prod(features[key]["shape"]))

    n_arms = dim("complementary_info.jaw_angle")

    def with_last(key: str, next_key: str) -> np.ndarray:
        now, nxt = _as_2d(arrays[key], dim(key)), _as_2d(arrays[next_key], dim(key))
        return np.concatenate([now, nxt[-1:]], axis=0).astype(np.float32)

    tip = with_last("complementary_info.tip_position", "complementary_info.next_tip_position")
    achieved, desired = split_environment_state(with_last(ENV_STATE, NEXT_ENV_STATE))
    return Trajectory(
        observation=with_last("observation.state", "next.observation.state"),
        achieved_goal=np.ascontiguousarray(achieved), desired_goal=np.ascontiguousarray(desired),
        action=_as_2d(arrays["action"], dim("action")).astype(np.float32),
        reward=arrays["next.reward"].reshape(-1).astype(np.float32),
        success=arrays["next.success"].reshape(-1).astype(bool),
        terminated=arrays["next.done"].reshape(-1).astype(bool),
        tip_position=tip.reshape(len(tip), n_arms, 3),
        jaw_angle=with_last("complementary_info.jaw_angle", "complementary_info.next_jaw_angle"),
        flags={**{f: arrays[f"complementary_info.{f}"].reshape(-1).astype(bool) for f in DEVICE_FLAGS},
               **_event_flags(arrays, n_arms),
               **({INTERVENTION: _as_2d(arrays[INTERVENTION_ARMS], n_arms).astype(bool)}
                  if INTERVENTION_ARMS in arrays else {})},
        policy_action=(_as_2d(arrays[POLICY_ACTION], dim("action")).astype(np.float32)
                       if POLICY_ACTION in arrays else None),
    )


def _event_flags(arrays: dict[str, np.ndarray], n_arms: int) -> dict[str, np.ndarray]:
    """The optional env events as the recorder got them: ``grasped`` (T, n_arms), ``drop`` (T,)."""
    events = {}
    if "complementary_info.grasped" in arrays:
        events["grasped"] = _as_2d(arrays["complementary_info.grasped"], n_arms).astype(bool)
    if "complementary_info.drop" in arrays:
        events["drop"] = arrays["complementary_info.drop"].reshape(-1).astype(bool)
    return events


class DatasetReader:
    """Episodes metadata, trajectories and transitions of a dataset as numpy, without lerobot.

    ``reader.episodes`` is one row per episode: ``episode_index``, ``length`` and the provenance columns
    (without the ``provenance/`` prefix). ``select`` filters it; ``trajectory``/``trajectories``/
    ``transitions`` read frames.
    """

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.info: dict = load_info(self.root)
        if not parquet_files(self.root, EPISODES_DIR):
            # A recording killed before its first checkpoint leaves its episode rows unwritten (they are written a
            # checkpoint at a time) and a data file without a footer: that is a dataset to repair, not an empty one.
            _check_readable(self.root)
            if int(self.info.get("total_episodes", 0)) > 0:
                raise DatasetError(f"{self.root}: info.json lists {self.info['total_episodes']} episodes but "
                                   f"{EPISODES_DIR}/ has no parquet file; the recording was interrupted before "
                                   "its first checkpoint — nothing can be recovered")
            self._meta = pa.table({"episode_index": pa.array([], pa.int64()), "length": pa.array([], pa.int64())})
        else:
            # Each episodes file's footer is parsed once (it describes ~300 stats columns: that parse is most
            # of the cost of opening), for the readability check and the read alike.
            tables, bad = [], []
            for path in parquet_files(self.root, DATA_DIR):
                try:
                    pq.read_metadata(path)
                except (pa.ArrowInvalid, OSError):
                    bad.append(path)
            for path in parquet_files(self.root, EPISODES_DIR):
                try:
                    tables.append(episode_rows(path))
                except (pa.ArrowInvalid, OSError):
                    bad.append(path)
            _check_readable(self.root, bad)
            self._meta = pa.concat_tables(tables, promote_options="default").sort_by("episode_index")
        self.episodes: pd.DataFrame = self._episodes_frame()
        self._row_of = {int(ep): i for i, ep in enumerate(self.episodes["episode_index"])}
        self._row_groups: dict[Path, np.ndarray] = {}   # (min, max) episode of each row group

    # ---------------------------------------------------------------- metadata

    def _episodes_frame(self) -> pd.DataFrame:
        meta = self._meta
        data = {"episode_index": column_to_numpy(meta.column("episode_index")).astype(np.int64),
                "length": column_to_numpy(meta.column("length")).astype(np.int64)}
        for name in meta.column_names:
            if name.startswith(PROVENANCE_PREFIX):
                data[name.removeprefix(PROVENANCE_PREFIX)] = meta.column(name).to_pylist()
        return pd.DataFrame(data)

    @property
    def features(self) -> dict:
        return self.info["features"]

    @property
    def fps(self) -> int:
        return int(self.info["fps"])

    def __len__(self) -> int:
        return len(self.episodes)

    def select(self, where: None | str | Callable[[dict], bool] | dict = None) -> list[int]:
        """Episode indices whose row matches ``where``.

        ``None``: all. A callable gets the row as a dict (columns of :attr:`episodes`). A dict maps a column
        to a value or to a set/list/tuple of accepted values, e.g.
        ``{"skill": "expert", "source": {"script", "haptic"}, "success": True}``. A string is a
        :mod:`surrol_data.datasets.where` expression, e.g. ``'skill == "expert" and success'``.
        """
        eps = self.episodes
        if where is None:
            return [int(e) for e in eps["episode_index"]]
        if isinstance(where, str):
            from surrol_data.datasets.where import WhereError, compile_where

            try:
                where = compile_where(where, eps.columns)
            except WhereError as e:
                raise DatasetError(str(e)) from None
        if callable(where):
            return [int(row["episode_index"]) for row in eps.to_dict("records") if where(row)]
        if not isinstance(where, dict):
            raise DatasetError(f"select(where=...) takes None, a callable or a dict, got {type(where).__name__}")
        mask = np.ones(len(eps), bool)
        for key, wanted in where.items():
            if key not in eps.columns:
                raise DatasetError(f"select: no column {key!r} in the episodes metadata; available: {list(eps.columns)}")
            if isinstance(wanted, (set, frozenset, list, tuple)):
                mask &= eps[key].isin(list(wanted)).to_numpy()
            else:
                mask &= (eps[key] == wanted).to_numpy()
        return [int(e) for e in eps["episode_index"][mask]]

    # ---------------------------------------------------------------- frames

    def _require_features(self, names: Iterable[str]) -> None:
        if is_schema1(self.features):
            raise DatasetError(f"{self.root} was written with surrol_data schema 1 (goals in "
                               "observation.achieved_goal / desired_goal): run `surrol-data upgrade "
                               f"{self.root}` to rewrite it in the current schema")
        missing = [n for n in names if n not in self.features]
        if missing:
            raise DatasetError(f"{self.root} lacks feature(s) {missing}: not written with the surrol_data schema "
                               "(see surrol_data.datasets.schema.frame_features)")

    def _dim(self, feature: str) -> int:
        return int(np.prod(self.features[feature]["shape"]))

    def _episode_row(self, ep: int) -> int:
        try:
            return self._row_of[int(ep)]
        except KeyError:
            raise DatasetError(f"episode {ep} is not in {self.root} "
                               f"(it holds {len(self)} episodes: indices {self.select()[:5]}...)") from None

    def _data_path(self, row: int) -> Path:
        chunk = int(self._meta.column("data/chunk_index")[row].as_py())
        file = int(self._meta.column("data/file_index")[row].as_py())
        return self.root / self.info["data_path"].format(chunk_index=chunk, file_index=file)

    def _groups_with(self, path: Path, ep: int) -> list[int]:
        """Row groups of ``path`` that may hold episode ``ep`` (from the parquet statistics)."""
        return self._groups_holding(path, [ep])

    def _groups_holding(self, path: Path, episodes: list[int]) -> list[int]:
        """Row groups of ``path`` that may hold any of ``episodes`` (from the parquet statistics; empty when the
        file has none: the caller reads the whole file)."""
        if path not in self._row_groups:
            md = pq.read_metadata(path)
            col = md.schema.names.index("episode_index")
            spans = []
            for i in range(md.num_row_groups):
                stats = md.row_group(i).column(col).statistics
                if stats is None or not stats.has_min_max:
                    spans = []  # no statistics: the caller reads the whole file
                    break
                spans.append((int(stats.min), int(stats.max)))
            self._row_groups[path] = np.asarray(spans, np.int64).reshape(-1, 2)
        spans = self._row_groups[path]
        wanted = np.unique(np.asarray(episodes, np.int64))
        if not len(spans) or not len(wanted):
            return []
        # the first wanted episode at or after each group's min: the group is needed if it is within the group
        at = np.searchsorted(wanted, spans[:, 0])
        inside = at < len(wanted)
        inside[inside] = wanted[at[inside]] <= spans[inside, 1]
        return np.flatnonzero(inside).tolist()

    def _episode_table(self, ep: int, columns: list[str]) -> pa.Table:
        path = self._data_path(self._episode_row(ep))
        cols = list(dict.fromkeys([*columns, "episode_index", "frame_index"]))
        groups = self._groups_with(path, ep)
        pf = pq.ParquetFile(path)
        table = pf.read_row_groups(groups, columns=cols) if groups else pf.read(columns=cols)
        table = table.filter(pc.equal(table.column("episode_index"), ep))
        return table.sort_by("frame_index")

    def _read_episodes(self, episodes: list[int] | None, columns: list[str]) -> pa.Table:
        """Rows of ``episodes`` (all if None) in dataset order, reading each data file once."""
        wanted = None
        paths = parquet_files(self.root, DATA_DIR)
        if episodes is not None:
            wanted = sorted({int(e) for e in episodes})
            rows = np.array([self._episode_row(ep) for ep in wanted], np.int64)
            chunks = column_to_numpy(self._meta.column("data/chunk_index"))[rows]
            files = column_to_numpy(self._meta.column("data/file_index"))[rows]
            # the files of those rows (by column, not one row's scalars at a time: 10,000 episodes)
            paths = sorted({self.root / self.info["data_path"].format(chunk_index=int(c), file_index=int(f))
                            for c, f in set(zip(chunks.tolist(), files.tolist()))})
        cols = list(dict.fromkeys([*columns, "episode_index", "index"]))
        tables = []
        for path in paths:
            if wanted is None:
                tables.append(pq.read_table(path, columns=cols))
                continue
            # only the row groups (lerobot writes one per episode) that hold wanted episodes when they are few: a
            # consolidated file holds thousands of episodes, most of them not asked for
            groups = self._groups_holding(path, wanted)
            if groups and 2 * len(groups) < len(self._row_groups[path]):
                table = pq.ParquetFile(path).read_row_groups(groups, columns=cols)
            else:   # most row groups wanted, or no statistics to choose by: the whole file in one read
                table = pq.read_table(path, columns=cols)
            tables.append(table.filter(pc.is_in(table.column("episode_index"), pa.array(wanted, pa.int64()))))
        if not tables:  # no episode asked for, or an empty dataset
            all_files = parquet_files(self.root, DATA_DIR)
            if not all_files:
                raise DatasetError(f"{self.root} has no data files: record at least one episode first")
            return pq.read_schema(all_files[0]).empty_table().select(cols)
        return pa.concat_tables(tables).sort_by("index")

    def _trajectory_from(self, table: pa.Table) -> Trajectory:
        return trajectory_from_table(table, self.features)

    def _event_columns(self) -> list[str]:
        """The optional columns this dataset has: env events (:func:`surrol_data.datasets.schema.event_features`) and
        who acted in an intervention session (:func:`~surrol_data.datasets.schema.intervention_features`)."""
        events = [f"complementary_info.{e}" for e in EVENT_FLAGS if f"complementary_info.{e}" in self.features]
        return events + [k for k in INTERVENTION_FEATURES if k in self.features]

    def trajectory(self, ep: int, images: bool = False) -> Trajectory:
        """Episode ``ep`` as a :class:`Trajectory` (T+1 observations, the last one included).

        ``images=True`` decodes the camera frames too (see :meth:`frames`); the dataset holds the image of each
        s_0..s_{T-1}, so the image of s_T repeats the last one.
        """
        columns = [*_TRANSITION_COLUMNS.values(), *_TRAJECTORY_EXTRA, *self._event_columns()]
        self._require_features(columns)
        table = self._episode_table(int(ep), columns)
        expected = int(self.episodes["length"].iloc[self._episode_row(ep)])
        if table.num_rows != expected:
            raise DatasetError(f"episode {ep}: {table.num_rows} frames in {self._data_path(self._episode_row(ep))}, "
                               f"metadata says {expected}; run `surrol-data repair {self.root}`")
        traj = self._trajectory_from(table)
        return self._with_images(traj, ep) if images else traj

    def _with_images(self, traj: Trajectory, ep: int) -> Trajectory:
        """``traj`` with episode ``ep``'s camera frames; the image of s_T repeats the last one (not stored)."""
        traj.images = {cam: np.concatenate([f, f[-1:]]) for cam, f in self.frames(ep).items()}
        return traj

    @property
    def cameras(self) -> list[str]:
        """Camera names (``observation.images.<name>`` video features), in feature order."""
        return [k.removeprefix("observation.images.") for k, ft in self.features.items()
                if ft["dtype"] == "video" and k.startswith("observation.images.")]

    def frames(self, ep: int) -> dict[str, np.ndarray]:
        """Episode ``ep``'s camera frames: name -> (T, H, W, 3) uint8, decoded from its segment of the video file."""
        from surrol_data.datasets.video import decode_segment

        row = self._episode_row(ep)
        length = int(self.episodes["length"].iloc[row])
        out = {}
        for cam in self.cameras:
            key = f"observation.images.{cam}"
            value = {c: self._meta.column(f"videos/{key}/{c}")[row].as_py()
                     for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")}
            path = self.root / self.info["video_path"].format(video_key=key, chunk_index=int(value["chunk_index"]),
                                                             file_index=int(value["file_index"]))
            out[cam] = decode_segment(path, float(value["from_timestamp"]), float(value["to_timestamp"]), self.fps,
                                      length)
        return out

    def trajectories(self, episodes: Iterable[int] | None = None, images: bool = False) -> list[Trajectory]:
        """Trajectories of ``episodes`` (all if None), in the order given, each data file read once (``images``: as
        :meth:`trajectory`)."""
        columns = [*_TRANSITION_COLUMNS.values(), *_TRAJECTORY_EXTRA, *self._event_columns()]
        self._require_features(columns)
        order = self.select() if episodes is None else [int(e) for e in episodes]
        table = self._read_episodes(order, columns)
        ep_col = column_to_numpy(table.column("episode_index"))
        # rows are sorted by global index, so each episode is one contiguous block
        starts = {int(e): int(i) for e, i in zip(*np.unique(ep_col, return_index=True), strict=True)}
        counts = dict(zip(*np.unique(ep_col, return_counts=True), strict=True))
        trajectories = [self._trajectory_from(table.slice(starts[ep], int(counts[ep]))) for ep in order]
        return [self._with_images(t, ep) for t, ep in zip(trajectories, order, strict=True)] if images else trajectories

    def transitions(self, episodes: Iterable[int] | None = None) -> dict[str, np.ndarray]:
        """Every (s_t, a_t, r_t, s_{t+1}) of ``episodes`` (all if None) as flat arrays, in dataset order.

        Keys: obs, achieved_goal, desired_goal, action, next_obs, next_achieved_goal, next_desired_goal
        (N, dim) float32 (the goals are the halves of ``observation.environment_state``); reward (N,) float32;
        done, success (N,) bool; episode_index (N,) int64.
        ``done`` is the env's ``terminated`` (don't bootstrap); episode ends are where episode_index changes.
        """
        self._require_features(_TRANSITION_COLUMNS.values())
        table = self._read_episodes(None if episodes is None else list(episodes), list(_TRANSITION_COLUMNS.values()))
        out = {}
        for key, name in _TRANSITION_COLUMNS.items():
            values = column_to_numpy(table.column(name))
            if key in _SCALAR_KEYS:
                out[key] = values.reshape(-1).astype(np.float32 if key == "reward" else bool)
            elif key in _GOAL_SPLIT:
                achieved, desired = split_environment_state(_as_2d(values, self._dim(name)).astype(np.float32))
                out.update(zip(_GOAL_SPLIT[key], map(np.ascontiguousarray, (achieved, desired)), strict=True))
            else:
                out[key] = _as_2d(values, self._dim(name)).astype(np.float32)
        out["episode_index"] = column_to_numpy(table.column("episode_index")).astype(np.int64)
        return out

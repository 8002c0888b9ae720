"""``surrol-data validate DIR``: every way a dataset can be wrong, each reported precisely.

Checks, in order (a check that makes the later ones meaningless stops the run):

1. ``format``: meta/info.json exists, is JSON, and is LeRobot v3.
2. ``parquet``: every data / episodes parquet file has its footer (not truncated by a killed recorder).
3. ``schema``: the frame features are the surrol_data schema (:func:`schema.frame_features`) with the right
   dtypes and shapes, whatever the task's dimensions.
4. ``provenance``: every :data:`schema.PROVENANCE_COLUMNS` column is in the episodes metadata, with its one
   type, no nulls, allowed choices, valid JSON, and ``episode_steps`` equal to the episode length.
5. ``counts``: info.json totals, episodes metadata rows and data rows agree; indices are contiguous.
6. ``values``: no NaN / inf in any float frame column; ``next.observation.*`` of frame t equals
   ``observation.*`` of frame t+1 within an episode.
   ``integrity``: each episode's provenance and video segment are what was recorded (the ``seal/*`` columns,
   :mod:`surrol_data.datasets.seals`), and a haptic episode's device trace says what its provenance says.
7. ``reward``: ``next.reward`` equals the task's ``compute_reward(next achieved goal, desired goal)`` (the env
   is made with ``gymnasium.make(env_id)`` from the dataset's metadata).
8. ``lerobot``: ``LeRobotDataset(repo_id, root=DIR)`` opens it offline and reads its first and last frame.

Each problem names the file / episode / column and says what to do.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import (
    DATA_DIR,
    EPISODES_DIR,
    INFO_PATH,
    DatasetError,
    column_to_numpy,
    episode_rows,
    load_info,
    parquet_files,
)
from surrol_data.datasets.seals import provenance_mismatches, trace_disagreements, video_mismatches
from surrol_data.datasets.schema import (
    PROVENANCE_CHOICES,
    PROVENANCE_SEAL,
    PROVENANCE_COLUMNS,
    FPS,
    PROVENANCE_PREFIX,
    SIDECAR_PATH,
    content_hash,
    ENV_STATE,
    NEXT_ENV_STATE,
    dims_from_features,
    frame_features,
    split_environment_state,
)

REPAIR_HINT = "run `surrol-data repair DIR`"
_MAX_LISTED = 5
_ARROW_TYPE_CHECK = {
    str: (pa.types.is_string, pa.types.is_large_string),
    bool: (pa.types.is_boolean,),
    int: (pa.types.is_integer,),
    float: (pa.types.is_floating,),
}
_LEROBOT_DEFAULT = ("timestamp", "frame_index", "episode_index", "index", "task_index")
_TRACE_DIR = "meta/device_traces"
_CHAINED = (("observation.state", "next.observation.state"),
            (ENV_STATE, NEXT_ENV_STATE),
            ("complementary_info.tip_position", "complementary_info.next_tip_position"),
            ("complementary_info.jaw_angle", "complementary_info.next_jaw_angle"))


@dataclass(frozen=True)
class Problem:
    check: str     # format | parquet | schema | provenance | counts | values | reward | sidecar | lerobot
    where: str     # the file, episode or column concerned
    message: str   # what is wrong and what to do

    def __str__(self) -> str:
        return f"[{self.check}] {self.where}: {self.message}"


def _listed(items) -> str:
    items = list(items)
    more = f" (+{len(items) - _MAX_LISTED} more)" if len(items) > _MAX_LISTED else ""
    return ", ".join(str(i) for i in items[:_MAX_LISTED]) + more


STAGES = ("files", "provenance", "frames", "episodes", "statistics", "videos", "reward", "lerobot")


def validate_dataset(root: str | Path, *, check_reward: bool = True, check_lerobot: bool = True,
                     check_videos: bool = True, frames: bool = True,
                     progress: Callable[[str], None] | None = None) -> list[Problem]:
    """All problems found in the dataset at ``root`` (empty list: it is valid). See the module docstring.

    ``frames=False`` checks the metadata only — what ``info`` shows: format, every parquet footer, schema,
    provenance and its seals, counts (the data files' row counts from their footers), tasks and sidecar — without
    reading a frame (the ``frames``, ``episodes``, ``statistics`` and ``videos`` stages and the device traces are
    left out). ``progress`` is called with the name of each stage of :data:`STAGES` as it starts (for a progress
    bar). Never raises on a damaged dataset: a check that fails unexpectedly is itself reported as a problem. A disk
    that refuses a write of the checks' own (LeRobot's cache, under ~/.cache) raises its OSError: that says nothing
    of the dataset.
    """
    root = Path(root)
    try:
        return _validate(root, check_reward and frames, check_lerobot and frames, check_videos and frames, frames,
                         progress or (lambda stage: None))
    except Exception as e:  # noqa: BLE001 - the promise is a list of problems, never a traceback
        from surrol_data.datasets.write_failure import disk_error

        refused = disk_error(e)
        if refused is not None:   # the disk refused a write of the checks' own (LeRobot's cache): no finding
            raise refused from e
        return [Problem("internal", str(root), f"validation stopped on {type(e).__name__}: {e}; the dataset is "
                                               f"damaged in a way no check names yet: try `surrol-data repair "
                                               f"{root}`")]


def _read_files(root: Path, frames: bool) -> tuple[list[Problem], list[tuple[Path, pa.Table]], list[tuple[Path, object]]]:
    """(problems, every meta/episodes file read whole, every data file read whole; when ``frames`` is False the
    data files' footers only, and meta/episodes without its statistics). Each file is read once: the checks below work on these tables (re-reading each file per
    check cost as much as the checks themselves)."""
    problems, meta_files, data_files = [], [], []
    for sub, out in ((EPISODES_DIR, meta_files), (DATA_DIR, data_files)):
        for path in parquet_files(root, sub):
            try:
                if frames:
                    out.append((path, pq.read_table(path)))
                elif sub == DATA_DIR:
                    out.append((path, pq.read_metadata(path)))
                else:   # the per-episode statistics (most of the file) are checked against the frames only
                    out.append((path, episode_rows(path)))
            except Exception as e:  # noqa: BLE001 - whatever pyarrow raises is the finding
                problems.append(Problem("parquet", str(path.relative_to(root)),
                                        f"cannot be read ({type(e).__name__}: {str(e)[:120]}): truncated, "
                                        f"overwritten or left by a killed writer; {REPAIR_HINT} to keep every "
                                        "intact episode"))
    return problems, meta_files, data_files


def _schema_of(content) -> pa.Schema:
    return content.schema if isinstance(content, pa.Table) else content.schema.to_arrow_schema()


def _validate(root: Path, check_reward: bool, check_lerobot: bool, check_videos: bool, frames: bool,
              stage: Callable[[str], None]) -> list[Problem]:
    problems: list[Problem] = []
    stage("files")
    try:
        info = load_info(root)
    except DatasetError as e:
        # a recording killed before it created its LeRobot files has no info.json: that, not the file, is the cause
        unfinished = _check_unfinished(root) if (root / "meta").is_dir() else []
        return unfinished or [Problem("format", INFO_PATH, f"{e}")]
    problems += _check_info(info, read_sidecar(root))
    problems += _check_unfinished(root)
    unreadable, meta_files, data_files = _read_files(root, frames)
    problems += unreadable
    if any(p.check == "parquet" for p in problems) or any(p.check == "format" for p in problems):
        return problems
    if not meta_files or not data_files:
        return problems + [Problem("format", str(root), f"no parquet files under {EPISODES_DIR}/ or {DATA_DIR}/: "
                                                        "the dataset holds no episode; record at least one")]
    schema_problems = _check_schema(info)
    if schema_problems:
        return problems + schema_problems
    stage("provenance")
    meta_tables = [table.append_column("__meta_file", pa.array([str(path.relative_to(root))] * table.num_rows))
                   for path, table in meta_files]
    try:
        meta_full = pa.concat_tables(meta_tables, promote_options="default").sort_by("episode_index")
    except (pa.ArrowInvalid, pa.ArrowTypeError) as e:
        return problems + [Problem("provenance", f"{EPISODES_DIR}/", f"its files disagree on a column's type ({e}); "
                                   "one type per column (use -1 / nan / '' for unknown): restore the edited file "
                                   f"from a copy, or {REPAIR_HINT}")]
    del meta_tables
    meta = meta_full.select([n for n in meta_full.column_names if not n.startswith("stats/")])
    provenance_problems = _check_provenance(meta)
    problems += provenance_problems
    column_problems = _check_columns(root, info, data_files)
    if column_problems:
        return problems + column_problems
    side = read_sidecar(root)
    if not frames:
        problems += _check_tasks(root, info, meta, None)
        problems += _check_counts_from_footers(root, info, meta, data_files)
        problems += _check_locations(root, info, meta, None)
        problems += _check_stats_file(root)
        problems += _check_sidecar(root, side, meta)
        if not provenance_problems:
            problems += _check_provenance_seals(meta, bool(side.get("seals")))
        return problems
    stage("frames")
    data = _read_data(info, data_files)
    del data_files
    problems += _check_tasks(root, info, meta, data)
    count_problems = _check_counts(info, meta, data)
    problems += count_problems
    if count_problems:
        return problems  # frame checks would only repeat the mismatch
    problems += _check_locations(root, info, meta, data)
    problems += _check_values(info, data)
    stage("episodes")
    if not any(p.where.endswith("content_hash") and "missing" in p.message for p in problems):
        problems += _check_episodes(info, meta, data)
    stage("statistics")
    problems += _check_stats(root, info, meta_full, data)
    problems += _check_sidecar(root, side, meta)
    problems += _check_traces(root, meta, data)
    if not provenance_problems:  # a column of the wrong type or with nulls is reported once, above
        problems += _check_provenance_seals(meta, bool(side.get("seals")))
    if check_videos:
        stage("videos")
        problems += _check_videos(root, info, meta_full)
        problems += _check_video_seals(root, info, meta, bool(side.get("seals")))
    if check_reward:
        stage("reward")
        problems += _check_reward(side, meta, data)
    if check_lerobot:
        stage("lerobot")
        problems += _check_lerobot(root, info)
    return problems


def _check_schema(info: dict) -> list[Problem]:
    features = info.get("features", {})
    try:
        dims = dims_from_features(features)
    except ValueError as e:
        return [Problem("schema", "meta/info.json features", f"{e}")]
    expected = frame_features(dims["obs_dim"], dims["goal_dim"], dims["act_dim"], dims["n_arms"],
                              cameras=dims["cameras"] or None)
    problems = []
    for key, want in expected.items():
        got = features.get(key)
        if got is None:
            problems.append(Problem("schema", key, "feature missing from meta/info.json; the dataset was not "
                                                   "written with surrol_data.datasets.schema.frame_features"))
        elif got["dtype"] != want["dtype"] or tuple(got["shape"]) != tuple(want["shape"]):
            problems.append(Problem("schema", key, f"is {got['dtype']}{tuple(got['shape'])}, expected "
                                                   f"{want['dtype']}{tuple(want['shape'])}"))
        elif want["dtype"] != "video" and (not isinstance(got.get("names"), list)
                                           or len(got["names"]) != int(np.prod(got["shape"]))
                                           or len(set(got["names"])) != len(got["names"])):
            problems.append(Problem("schema", key, f"names {got.get('names')!r} do not name each of its "
                                                   f"{int(np.prod(got['shape']))} dimensions once; run "
                                                   "`surrol-data upgrade DIR`"))
    for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        if key not in features:
            problems.append(Problem("schema", key, "LeRobot bookkeeping feature missing from meta/info.json"))
    return problems


def _check_provenance(meta: pa.Table) -> list[Problem]:
    problems = []
    episodes = column_to_numpy(meta.column("episode_index"))
    lengths = column_to_numpy(meta.column("length")) if "length" in meta.column_names else None
    for name, typ in PROVENANCE_COLUMNS.items():
        column = PROVENANCE_PREFIX + name
        where = f"meta/episodes column {column}"
        if column not in meta.column_names:
            problems.append(Problem("provenance", where, f"missing: every episode needs its {name} ({typ.__name__}); "
                                                         "record through DatasetRecorder, which writes all "
                                                         f"{len(PROVENANCE_COLUMNS)} provenance columns"))
            continue
        col = meta.column(column)
        if not any(check(col.type) for check in _ARROW_TYPE_CHECK[typ]):
            problems.append(Problem("provenance", where, f"has type {col.type}, expected {typ.__name__} "
                                                         "(one type per column; use -1 / nan / '' for unknown)"))
            continue
        if col.null_count:
            nulls = episodes[column_to_numpy(col.is_null())]
            problems.append(Problem("provenance", where, f"null in episode(s) {_listed(nulls)}; provenance never "
                                                         "holds None (use -1 / nan / '' for unknown)"))
            continue
        values = col.to_pylist()
        if name in PROVENANCE_CHOICES:
            bad = [(int(e), v) for e, v in zip(episodes, values, strict=True) if v not in PROVENANCE_CHOICES[name]]
            if bad:
                problems.append(Problem("provenance", where, f"episode(s) {_listed(e for e, _ in bad)} hold "
                                                             f"{sorted({v for _, v in bad})}; allowed: "
                                                             f"{list(PROVENANCE_CHOICES[name])}"))
        if name in ("operator_params", "device_settings"):
            bad = []
            for e, v in zip(episodes, values, strict=True):
                try:
                    json.loads(v)
                except json.JSONDecodeError:
                    bad.append(int(e))
            if bad:
                problems.append(Problem("provenance", where, f"episode(s) {_listed(bad)} are not JSON text"))
        if name == "episode_steps" and lengths is not None:
            bad = [int(e) for e, v, n in zip(episodes, values, lengths, strict=True) if v != n]
            if bad:
                problems.append(Problem("provenance", where, f"episode(s) {_listed(bad)}: episode_steps differs "
                                                             "from the episode length in meta/episodes"))
    return problems


def _read_data(info: dict, data_files: list[tuple[Path, pa.Table]]) -> pa.Table:
    """Every non-video frame column of the data files read, plus ``__file``: the position of the file each row
    came from."""
    names = [k for k, ft in info["features"].items() if ft["dtype"] not in ("video", "image", "string")]
    tables = []
    for i, (_, table) in enumerate(data_files):
        table = table.select([n for n in names if n in table.column_names])
        tables.append(table.append_column("__file", pa.array(np.full(table.num_rows, i, np.int64))))
    return pa.concat_tables(tables, promote_options="default").sort_by("index")


def _check_columns(root: Path, info: dict, data_files: list[tuple[Path, object]]) -> list[Problem]:
    """Every data file stores each feature with the width info.json declares (and has every feature)."""
    problems = []
    for path, content in data_files:
        schema = _schema_of(content)
        for name, ft in info["features"].items():
            if ft["dtype"] in ("video", "string"):
                continue
            if name not in schema.names:
                problems.append(Problem("schema", f"{path.relative_to(root)} column {name}",
                                        "missing from the data file though info.json declares it; restore the file "
                                        f"or {REPAIR_HINT}"))
                continue
            typ = schema.field(name).type
            declared = int(np.prod(ft["shape"]))
            if pa.types.is_list(typ) or pa.types.is_large_list(typ):
                # lerobot's own tools (aggregate_datasets, lerobot-edit-dataset) write vectors through pandas as
                # variable-length lists: the same values, so accepted when every row holds the declared count
                column = (content.column(name) if isinstance(content, pa.Table)
                          else pq.read_table(path, columns=[name]).column(0))
                lengths = set(pc.list_value_length(column).to_pylist())
                width = lengths.pop() if len(lengths) == 1 else f"{sorted(map(str, lengths))} (varying)"
            else:
                width = typ.list_size if pa.types.is_fixed_size_list(typ) else 1
            if ft["dtype"] == "image":
                declared = width
            if width != declared:
                problems.append(Problem("schema", f"meta/info.json features.{name}.shape",
                                        f"declares {list(ft['shape'])} but {path.relative_to(root)} stores {width} "
                                        "values per frame; info.json was edited: restore the shape"))
    return problems


def _check_info(info: dict, side: dict) -> list[Problem]:
    problems = []
    where = INFO_PATH
    fps = info.get("fps")
    if fps != FPS:
        problems.append(Problem("format", f"{where} fps", f"is {fps!r}; surrol_data records at {FPS} frames/s (one "
                                                          "control period per frame): timestamps and every duration "
                                                          f"derived from them would be wrong; set it back to {FPS}"))
    elif side and side.get("fps", FPS) != fps:
        problems.append(Problem("format", f"{where} fps", f"is {fps}, {SIDECAR_PATH} says {side.get('fps')}"))
    for key in ("data_path", "video_path", "features", "total_episodes", "total_frames", "total_tasks"):
        if key not in info:
            problems.append(Problem("format", f"{where} {key}", "missing; LeRobot cannot locate or count the "
                                                                "files without it: restore info.json (repair "
                                                                "rewrites it from the surviving files)"))
    for key in ("total_episodes", "total_frames", "total_tasks"):
        if key in info and not isinstance(info[key], int):
            problems.append(Problem("format", f"{where} {key}", f"is {info[key]!r}, expected an integer"))
    if not isinstance(info.get("features", {}), dict):
        problems.append(Problem("format", f"{where} features", "is not a mapping of feature name to spec"))
    return problems


def _check_unfinished(root: Path) -> list[Problem]:
    from surrol_data.datasets.repair import killed_recording
    from surrol_data.datasets.lock import writer_pid

    holder = writer_pid(root)
    if holder is not None:
        return [Problem("unfinished", str(root), f"is being written right now (pid {holder or '?'}); validate it "
                                                 "once the recording has finished")]
    from surrol_data.datasets.readonly_view import is_writable

    if killed_recording(root) and not is_writable(root):
        hint = (f"it is on a disk that cannot be written here: copy it to a writable folder and run `surrol-data "
                "repair` on the copy (our commands read a repaired copy of it meanwhile)")
    else:
        hint = f"{REPAIR_HINT} (our commands do it automatically)"
    return [Problem("unfinished", str(root), f"{why}: a recording was killed; {hint} to keep every finished episode")
            for why in killed_recording(root)]   # files without a footer: the parquet check names each one


def _check_tasks(root: Path, info: dict, meta: pa.Table, data: pa.Table | None) -> list[Problem]:
    """meta/tasks.parquet against info.json and meta/episodes, and each frame's task_index (without ``data``: the
    metadata only)."""
    path = root / "meta" / "tasks.parquet"
    try:
        tasks = pq.read_table(path).to_pandas()
        names = list(tasks.index if "task" not in tasks.columns else tasks["task"])
        indices = list(tasks["task_index"])
    except Exception as e:  # noqa: BLE001
        return [Problem("tasks", "meta/tasks.parquet", f"cannot be read ({type(e).__name__}); LeRobot needs it to "
                                                       f"name each frame's task: {REPAIR_HINT}")]
    problems = []
    if indices != list(range(len(names))):
        problems.append(Problem("tasks", "meta/tasks.parquet task_index", f"is {indices}, expected 0..{len(names) - 1}"))
    if info.get("total_tasks") != len(names):
        problems.append(Problem("tasks", "meta/info.json total_tasks", f"says {info.get('total_tasks')}, "
                                                                       f"meta/tasks.parquet has {len(names)}; "
                                                                       f"{REPAIR_HINT}"))
    if "tasks" in meta.column_names:
        used = {t for row in meta.column("tasks").to_pylist() for t in (row or [])}
        unknown = sorted(used - set(names))
        if unknown:
            problems.append(Problem("tasks", "meta/tasks.parquet", f"lacks task(s) {unknown} that meta/episodes "
                                                                   f"names; {REPAIR_HINT}"))
    if data is None:
        return problems
    task_index = column_to_numpy(data.column("task_index")).astype(np.int64).reshape(-1)
    bad = np.flatnonzero((task_index < 0) | (task_index >= len(names)))
    if len(bad):
        episodes = column_to_numpy(data.column("episode_index")).reshape(-1)
        problems.append(Problem("tasks", "data/ task_index", f"out of range 0..{len(names) - 1} in episode(s) "
                                                             f"{_listed(np.unique(episodes[bad]))}; the frames "
                                                             "point at a task that does not exist: re-record or "
                                                             "drop those episodes"))
    return problems


def _check_locations(root: Path, info: dict, meta: pa.Table, data: pa.Table | None) -> list[Problem]:
    """Each episode's rows are where meta/episodes says (file, from/to index); without ``data``, what the metadata
    says of itself (from/to index against the lengths, each row in the file it names)."""
    problems = []
    files = [str(p.relative_to(root)) for p in parquet_files(root, DATA_DIR)]
    episodes = column_to_numpy(meta.column("episode_index")).astype(np.int64)
    lengths = column_to_numpy(meta.column("length")).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    for name, expected in (("dataset_from_index", starts), ("dataset_to_index", starts + lengths)):
        if name in meta.column_names:
            got = column_to_numpy(meta.column(name)).astype(np.int64)
            bad = episodes[got != expected]
            if len(bad):
                problems.append(Problem("counts", f"meta/episodes {name}", f"wrong for episode(s) {_listed(bad)}; "
                                                                           f"LeRobot would read other frames: {REPAIR_HINT}"))
    if {"meta/episodes/chunk_index", "meta/episodes/file_index"} <= set(meta.column_names):
        said = [EPISODES_DIR + f"/chunk-{int(c):03d}/file-{int(f):03d}.parquet" for c, f in zip(
            column_to_numpy(meta.column("meta/episodes/chunk_index")),
            column_to_numpy(meta.column("meta/episodes/file_index")), strict=True)]
        actual = meta.column("__meta_file").to_pylist()
        bad = [f"{ep} (says {s_}, is in {a})" for ep, s_, a in zip(episodes, said, actual, strict=True) if s_ != a]
        if bad:
            problems.append(Problem("counts", "meta/episodes meta/episodes/file_index", "episode(s) " + _listed(bad)
                                    + f": metadata rows are not in the file they name (swapped files?); {REPAIR_HINT}"))
    if data is None:
        return problems
    data_file = column_to_numpy(data.column("__file")).astype(np.int64)
    first_row = starts
    wrong = []
    for ep, row, chunk, file in zip(episodes, first_row, column_to_numpy(meta.column("data/chunk_index")),
                                    column_to_numpy(meta.column("data/file_index")), strict=True):
        said = info["data_path"].format(chunk_index=int(chunk), file_index=int(file))
        actual = files[data_file[row]] if row < len(data_file) else "?"
        if said != actual:
            wrong.append(f"{ep} (metadata {said}, frames in {actual})")
    if wrong:
        problems.append(Problem("counts", "meta/episodes data/file_index", "episode(s) " + _listed(wrong)
                                + f": the metadata points at the wrong data file (swapped files?); {REPAIR_HINT}"))
    return problems


def _episode_slices(meta: pa.Table):
    episodes = column_to_numpy(meta.column("episode_index")).astype(np.int64)
    lengths = column_to_numpy(meta.column("length")).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    return list(zip(episodes.tolist(), starts.tolist(), lengths.tolist(), strict=True))


def _check_episodes(info: dict, meta: pa.Table, data: pa.Table) -> list[Problem]:
    """Per episode: stored content hash, provenance metrics recomputed, actions in range, timestamps, duplicates."""
    features = {k: v for k, v in info["features"].items() if k not in _LEROBOT_DEFAULT}
    numeric = {k: column_to_numpy(data.column(k)).reshape(data.num_rows, -1)
               for k, ft in features.items() if ft["dtype"] not in ("video", "image", "string")}
    prov = {name: meta.column(PROVENANCE_PREFIX + name).to_pylist() for name in PROVENANCE_COLUMNS
            if PROVENANCE_PREFIX + name in meta.column_names}
    slices = _episode_slices(meta)
    hash_bad, dup, metric_bad = [], {}, {}
    stored_hashes = prov.get("content_hash", [None] * len(slices))
    for row, (ep, start, length) in enumerate(slices):
        digest = content_hash({k: v[start:start + length] for k, v in numeric.items()}, features)
        stored = stored_hashes[row]
        if stored is not None and digest != stored:
            hash_bad.append(ep)
        dup.setdefault(stored or digest, []).append(ep)
    computed = _recorded_metrics(info, data, numeric, [length for _, _, length in slices])
    for name, values in computed.items():
        if name not in prov:
            continue
        stored_values = prov[name]
        if values.dtype.kind == "f":
            stored_array = np.array([np.nan if v is None else v for v in stored_values], np.float64)
            same = np.isclose(stored_array, values, rtol=1e-4, atol=1e-4, equal_nan=True)
        else:
            same = np.array([v == c for v, c in zip(stored_values, values.tolist(), strict=True)], bool)
        for row in np.flatnonzero(~same):
            metric_bad.setdefault(name, []).append(f"{slices[row][0]} (stored {stored_values[row]}, frames give "
                                                   f"{values[row].item()})")
    problems = []
    if hash_bad:
        problems.append(Problem("values", "meta/episodes provenance/content_hash", f"episode(s) {_listed(hash_bad)}: "
                                "the frames in data/ are not the frames that were recorded (values changed, rows "
                                "swapped or the hash edited); re-record those episodes or drop them with "
                                "`surrol-data filter`"))
    for name, bad in metric_bad.items():
        problems.append(Problem("provenance", f"meta/episodes column {PROVENANCE_PREFIX}{name}", "episode(s) "
                                + _listed(bad) + " disagree with the recorded frames; the metadata or the frames "
                                "were altered: re-record or drop those episodes"))
    copies = [eps for eps in dup.values() if len(eps) > 1]
    if copies:
        problems.append(Problem("duplicates", "meta/episodes provenance/content_hash",
                                "identical episodes " + _listed("=".join(map(str, eps)) for eps in copies)
                                + "; keep one copy (`surrol-data merge OUT DIR --drop-duplicates`)"))
    if "action" in numeric:
        episodes = column_to_numpy(data.column("episode_index")).astype(np.int64).reshape(-1)
        out = np.flatnonzero((np.abs(numeric["action"]) > 1.0 + 1e-6).any(axis=1))
        if len(out):
            problems.append(Problem("values", "column action", f"outside the env's action range [-1, 1] in "
                                    f"episode(s) {_listed(np.unique(episodes[out]))} (max |a| = "
                                    f"{np.abs(numeric['action'][out]).max():.3g}); actions were scaled or "
                                    "corrupted: re-record or drop those episodes"))
    timestamps = column_to_numpy(data.column("timestamp")).reshape(-1).astype(np.float64)
    frame = column_to_numpy(data.column("frame_index")).reshape(-1).astype(np.float64)
    fps = info.get("fps") if isinstance(info.get("fps"), (int, float)) and info.get("fps") else FPS
    bad = np.flatnonzero(~np.isclose(timestamps, frame / fps, rtol=0, atol=1e-4))
    if len(bad):
        episodes = column_to_numpy(data.column("episode_index")).astype(np.int64).reshape(-1)
        problems.append(Problem("values", "column timestamp", f"is not frame_index / fps ({fps}) in episode(s) "
                                f"{_listed(np.unique(episodes[bad]))}; LeRobot aligns frames and video by it: "
                                "re-record or drop those episodes"))
    return problems


def _recorded_metrics(info: dict, data: pa.Table, numeric: dict, lengths: list[int]) -> dict[str, np.ndarray]:
    """The proficiency metrics stored with each episode, recomputed from the frames (empty when a column they need
    is missing or malformed: the other checks report that)."""
    from surrol_data.datasets.episode_metrics import recorded_metrics

    features = info["features"]
    needed = ("next.success", "action", "complementary_info.tip_position", "complementary_info.next_tip_position",
              "complementary_info.jaw_angle", "complementary_info.clutch")
    if any(name not in numeric for name in needed):
        return {}
    try:
        return recorded_metrics(np.asarray(lengths, np.int64), numeric["next.success"], numeric["action"],
                                numeric["complementary_info.tip_position"],
                                numeric["complementary_info.next_tip_position"], numeric["complementary_info.clutch"],
                                n_arms=int(np.prod(features["complementary_info.jaw_angle"]["shape"])))
    except (ValueError, IndexError):
        return {}


_STAT_TOL = dict(rtol=1e-3, atol=1e-4)


def _stored_stat(column: list, row: int, value: np.ndarray) -> bool:
    stored = column[row]
    return stored is not None and np.allclose(np.asarray(stored, np.float64).reshape(-1), value, **_STAT_TOL)


def _stored_stats_agree(meta_full: pa.Table, col: str, rows: np.ndarray, got: np.ndarray) -> np.ndarray:
    """Per row of ``rows``: whether the stored ``col`` equals ``got`` (one row per entry of ``rows``)."""
    column = meta_full.column(col)
    if not column.null_count:
        stored = column_to_numpy(column)
        stored = stored.reshape(len(stored), -1) if stored.size else stored.reshape(len(stored), 0)
        if stored.shape[1] == got.shape[1]:
            return np.isclose(stored[rows], got, **_STAT_TOL).all(axis=1)
    values = column.to_pylist()   # nulls or other widths: one row at a time
    return np.array([_stored_stat(values, int(r), g) for r, g in zip(rows, got, strict=True)], bool)


def _check_stats(root: Path, info: dict, meta_full: pa.Table, data: pa.Table) -> list[Problem]:
    """Per-episode stats (meta/episodes stats/*) against the frames, and meta/stats.json against those."""
    problems = []
    floats = [k for k, ft in info["features"].items() if ft["dtype"].startswith("float") and k in data.column_names]
    bad_episode: dict[str, list[int]] = {}
    agg: dict[str, dict] = {}
    slices = _episode_slices(meta_full)
    episodes = np.array([ep for ep, _, _ in slices], np.int64)
    starts = np.array([start for _, start, _ in slices], np.int64)
    lengths = np.array([length for _, _, length in slices], np.int64)
    rows = np.flatnonzero(lengths > 0)
    for k in floats:
        values = column_to_numpy(data.column(k)).reshape(data.num_rows, -1).astype(np.float64)
        if not len(rows):
            continue
        # episodes are contiguous blocks of rows: one reduceat per statistic instead of a loop over episodes
        finite = np.logical_and.reduceat(np.isfinite(values).all(axis=1), starts[rows])
        sums = np.add.reduceat(values, starts[rows], axis=0)
        got = {"min": np.minimum.reduceat(values, starts[rows], axis=0),
               "max": np.maximum.reduceat(values, starts[rows], axis=0),
               "mean": sums / lengths[rows, None]}
        checked = rows[finite]   # an episode with NaN / inf is reported by the values check
        for stat, value in got.items():
            col = f"stats/{k}/{stat}"
            if col in meta_full.column_names and len(checked):
                agree = _stored_stats_agree(meta_full, col, checked, value[finite])
                if not agree.all():
                    bad_episode.setdefault(f"{k} {stat}", []).extend(episodes[checked[~agree]].tolist())
        if len(checked):
            agg[k] = {"min": got["min"][finite].min(0), "max": got["max"][finite].max(0),
                      "sum": sums[finite].sum(0), "n": int(lengths[checked].sum())}
    for what, eps in bad_episode.items():
        problems.append(Problem("stats", f"meta/episodes stats/{what.replace(' ', '/')}", f"episode(s) {_listed(eps)} "
                                "disagree with their frames; the statistics (used to normalise policy inputs) or "
                                f"the frames were altered: {REPAIR_HINT} rewrites the statistics"))
    stats, unreadable = _read_stats_file(root)
    if unreadable:
        return problems + unreadable
    wrong = []
    for k, a in agg.items():
        if not a["n"]:
            continue
        got = {"min": a["min"], "max": a["max"], "mean": a["sum"] / a["n"]}
        for stat, value in got.items():
            stored = stats.get(k, {}).get(stat) if isinstance(stats.get(k), dict) else None
            try:
                ok = stored is not None and np.allclose(np.asarray(stored, np.float64).reshape(-1), value, **_STAT_TOL)
            except (TypeError, ValueError):
                ok = False
            if not ok:
                wrong.append(f"{k}/{stat}")
    if wrong:
        problems.append(Problem("stats", "meta/stats.json", f"{_listed(wrong)} disagree with the frames of the "
                                "dataset; policies normalise with these: " + REPAIR_HINT + " rewrites them"))
    return problems


def _read_stats_file(root: Path) -> tuple[dict, list[Problem]]:
    """(meta/stats.json, []) or ({}, the problem that it is missing or not JSON)."""
    try:
        stats = json.loads((root / "meta" / "stats.json").read_text())
    except (OSError, json.JSONDecodeError) as e:
        return {}, [Problem("stats", "meta/stats.json", f"missing or not JSON ({type(e).__name__}); LeRobot "
                                                        f"normalises with it: {REPAIR_HINT} rewrites it")]
    return stats, []


def _check_stats_file(root: Path) -> list[Problem]:
    return _read_stats_file(root)[1]


def _check_sidecar(root: Path, side: dict, meta: pa.Table) -> list[Problem]:
    if not side:
        return [Problem("sidecar", SIDECAR_PATH, "missing or not JSON: dataset-level facts (task, env id) are "
                                                 "unknown; the dataset was not written by DatasetRecorder (restore "
                                                 "the file from a copy)")]
    problems = []
    for key in ("task", "env_id"):
        column = PROVENANCE_PREFIX + key
        if column in meta.column_names:
            values = set(meta.column(column).to_pylist())
            if side.get(key) not in values or len(values) != 1:
                problems.append(Problem("sidecar", f"{SIDECAR_PATH} {key}", f"is {side.get(key)!r}, the episodes say "
                                        f"{sorted(map(str, values))}; one dataset holds one task: fix the sidecar "
                                        "or split the dataset"))
    return problems


def _check_traces(root: Path, meta: pa.Table, data: pa.Table) -> list[Problem]:
    """Haptic sessions save each episode's device trace; it must be there, readable, and of that episode."""
    folder = root / _TRACE_DIR
    if not folder.is_dir() or PROVENANCE_PREFIX + "source" not in meta.column_names:
        return []
    problems = []
    sources = meta.column(PROVENANCE_PREFIX + "source").to_pylist()
    provenance = {name: meta.column(PROVENANCE_PREFIX + name).to_pylist() for name in PROVENANCE_COLUMNS
                  if PROVENANCE_PREFIX + name in meta.column_names}
    actions = column_to_numpy(data.column("action")).reshape(data.num_rows, -1)
    for row, (ep, start, length) in enumerate(_episode_slices(meta)):
        path = folder / f"episode_{ep:06d}.npz"
        rel = str(path.relative_to(root))
        if not path.exists():
            if sources[row] == "haptic":
                problems.append(Problem("traces", rel, f"missing: episode {ep} was recorded by a device but its trace "
                                                       "is gone (replay and the device-rate metrics need it); "
                                                       "restore it from a copy"))
            continue
        try:
            with np.load(path, allow_pickle=False) as z:
                recorded = np.asarray(z["actions"], np.float32)
                trace_meta = json.loads(str(z["meta"]))
        except Exception as e:  # noqa: BLE001
            problems.append(Problem("traces", rel, f"cannot be read ({type(e).__name__}); episode {ep}'s device "
                                                   "trace is damaged: restore it from a copy"))
            continue
        said = {name: values[row] for name, values in provenance.items()}
        differ = trace_disagreements(trace_meta if isinstance(trace_meta, dict) else {}, said)
        if differ:
            problems.append(Problem("integrity", rel, f"episode {ep}: its device trace contradicts its provenance ("
                                                      + "; ".join(differ) + "): the provenance in meta/episodes was "
                                                      "edited, or the trace belongs to another episode; restore "
                                                      "the dataset from a copy"))
        if recorded.shape != actions[start:start + length].shape or not np.allclose(
                recorded, actions[start:start + length], atol=1e-6):
            problems.append(Problem("traces", rel, f"its actions are not episode {ep}'s actions (a trace of another "
                                                   "episode, or altered): restore the right file"))
    for path in sorted(folder.glob("episode_*.npz")):
        try:
            ep = int(path.stem.split("_")[1])
        except ValueError:
            ep = -1
        if not 0 <= ep < meta.num_rows:
            problems.append(Problem("traces", str(path.relative_to(root)), "belongs to no episode of the dataset "
                                                                           f"; {REPAIR_HINT} moves it aside"))
    return problems


_RESTORE = "restore the dataset from a copy, or drop those episodes with `surrol-data filter`"


def _check_provenance_seals(meta: pa.Table, sealed: bool) -> list[Problem]:
    bad, missing = provenance_mismatches(meta, sealed)
    problems = []
    if bad:
        problems.append(Problem("integrity", f"meta/episodes {PROVENANCE_SEAL}", f"episode(s) {_listed(bad)}: the "
                                "provenance is not what was recorded (a value such as operator_id or skill was "
                                f"edited after recording); {_RESTORE}"))
    if missing:
        problems.append(Problem("integrity", f"meta/episodes {PROVENANCE_SEAL}", f"episode(s) {_listed(missing)} "
                                f"have no seal, though {SIDECAR_PATH} says every episode is sealed (the column was "
                                f"removed or emptied); {_RESTORE}"))
    return problems


def _check_video_seals(root: Path, info: dict, meta: pa.Table, sealed: bool) -> list[Problem]:
    problems = []
    for rel, (bad, missing) in video_mismatches(root, info, meta, sealed).items():
        if bad:
            problems.append(Problem("integrity", rel, f"episode(s) {_listed(bad)}: the camera frames in this file "
                                    "are not the ones recorded with them (another recording's video copied over "
                                    f"it, or re-encoded); {_RESTORE}"))
        if missing:
            problems.append(Problem("integrity", rel, f"episode(s) {_listed(missing)} have no video seal, though "
                                    f"{SIDECAR_PATH} says every episode is sealed; {_RESTORE}"))
    return problems


def _check_videos(root: Path, info: dict, meta_full: pa.Table) -> list[Problem]:
    from surrol_data.datasets.repair import _video_ok

    keys = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
    problems = []
    for key in keys:
        needed: dict[str, tuple[float, list[int]]] = {}
        for r in meta_full.select([c for c in meta_full.column_names if c.startswith(f"videos/{key}/")
                                   or c in ("episode_index", "length")]).to_pylist():
            ep = int(r["episode_index"])
            start, end = r.get(f"videos/{key}/from_timestamp"), r.get(f"videos/{key}/to_timestamp")
            if start is None or end is None or abs((end - start) - r["length"] / FPS) > 1e-3:
                problems.append(Problem("videos", f"meta/episodes videos/{key}/*_timestamp", f"episode {ep}: the "
                                        f"segment [{start}, {end}] s is not its {r['length']} frames at {FPS} fps; "
                                        f"{REPAIR_HINT}"))
                continue
            rel = info["video_path"].format(video_key=key, chunk_index=r[f"videos/{key}/chunk_index"],
                                            file_index=r[f"videos/{key}/file_index"])
            end_before, eps = needed.get(rel, (0.0, []))
            needed[rel] = (max(end_before, end), eps + [ep])
        for rel, (end, eps) in needed.items():
            if not _video_ok(root / rel, end):
                problems.append(Problem("videos", rel, f"missing, unreadable or shorter than {end:.1f} s: the camera "
                                                       f"frames of episode(s) {_listed(eps)} are lost; "
                                                       f"{REPAIR_HINT} keeps the other episodes"))
    return problems


def _check_counts(info: dict, meta: pa.Table, data: pa.Table) -> list[Problem]:
    problems = []
    episodes = column_to_numpy(meta.column("episode_index")).astype(np.int64)
    lengths = column_to_numpy(meta.column("length")).astype(np.int64)
    total_episodes, total_frames = int(info.get("total_episodes", -1)), int(info.get("total_frames", -1))
    data_episodes = column_to_numpy(data.column("episode_index")).astype(np.int64)
    distinct, counts = np.unique(data_episodes, return_counts=True)
    if total_episodes != len(episodes):
        problems.append(Problem("counts", "meta/info.json total_episodes",
                                f"says {total_episodes}, meta/episodes has {len(episodes)} rows; "
                                f"{REPAIR_HINT} to rewrite info.json from the episodes that are complete"))
    if len(distinct) != len(episodes):
        problems.append(Problem("counts", "data/", f"holds frames of {len(distinct)} episodes, meta/episodes lists "
                                                   f"{len(episodes)}; {REPAIR_HINT}"))
    if total_frames != data.num_rows:
        problems.append(Problem("counts", "meta/info.json total_frames",
                                f"says {total_frames}, the data files hold {data.num_rows} frames; {REPAIR_HINT}"))
    if not np.array_equal(episodes, np.arange(len(episodes))):
        problems.append(Problem("counts", "meta/episodes episode_index",
                                f"not 0..{len(episodes) - 1} without gaps or repeats (got {_listed(episodes)}); "
                                "rebuild the dataset with `surrol-data merge OUT DIR`"))
    per_episode = dict(zip(distinct.tolist(), counts.tolist(), strict=True))
    wrong = [(int(e), int(n), per_episode.get(int(e), 0)) for e, n in zip(episodes, lengths, strict=True)
             if per_episode.get(int(e), 0) != n]
    if wrong:
        problems.append(Problem("counts", "meta/episodes length", "episode(s) " + _listed(
            f"{e} (metadata {n}, data {d})" for e, n, d in wrong) + f" disagree with the data files; {REPAIR_HINT}"))
    if not problems:
        index = column_to_numpy(data.column("index")).astype(np.int64)
        if not np.array_equal(index, np.arange(len(index))):
            problems.append(Problem("counts", "data/ index", "global frame index is not 0..N-1 in order"))
        frame = column_to_numpy(data.column("frame_index")).astype(np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        expected = np.arange(len(frame)) - np.repeat(starts, lengths)
        if not np.array_equal(frame, expected):
            bad = np.unique(data_episodes[frame != expected])
            problems.append(Problem("counts", "data/ frame_index", f"episode(s) {_listed(bad)}: frame_index is not "
                                                                   "0..T-1 in order"))
    return problems


def _check_counts_from_footers(root: Path, info: dict, meta: pa.Table, data_files: list) -> list[Problem]:
    """:func:`_check_counts` without reading a frame: info.json totals and meta/episodes against each other, and
    the frames each data file holds (its footer's row count) against the episodes that meta/episodes puts in it."""
    problems = []
    episodes = column_to_numpy(meta.column("episode_index")).astype(np.int64)
    lengths = column_to_numpy(meta.column("length")).astype(np.int64)
    total_episodes, total_frames = int(info.get("total_episodes", -1)), int(info.get("total_frames", -1))
    stored = {str(path.relative_to(root)): content.num_rows for path, content in data_files}
    if total_episodes != len(episodes):
        problems.append(Problem("counts", "meta/info.json total_episodes",
                                f"says {total_episodes}, meta/episodes has {len(episodes)} rows; "
                                f"{REPAIR_HINT} to rewrite info.json from the episodes that are complete"))
    if total_frames != sum(stored.values()):
        problems.append(Problem("counts", "meta/info.json total_frames",
                                f"says {total_frames}, the data files hold {sum(stored.values())} frames; "
                                f"{REPAIR_HINT}"))
    if not np.array_equal(episodes, np.arange(len(episodes))):
        problems.append(Problem("counts", "meta/episodes episode_index",
                                f"not 0..{len(episodes) - 1} without gaps or repeats (got {_listed(episodes)}); "
                                "rebuild the dataset with `surrol-data merge OUT DIR`"))
    said: dict[str, int] = {}
    for chunk, file, n in zip(column_to_numpy(meta.column("data/chunk_index")),
                              column_to_numpy(meta.column("data/file_index")), lengths, strict=True):
        rel = info["data_path"].format(chunk_index=int(chunk), file_index=int(file))
        said[rel] = said.get(rel, 0) + int(n)
    wrong = [f"{rel} (metadata {said.get(rel, 0)}, file {stored.get(rel, 0)})"
             for rel in sorted(set(said) | set(stored)) if said.get(rel, 0) != stored.get(rel, 0)]
    if wrong:
        problems.append(Problem("counts", "meta/episodes length", "the frames of " + _listed(wrong) + " disagree "
                                "with the episode lengths meta/episodes puts in those files; " + REPAIR_HINT))
    return problems


def _check_values(info: dict, data: pa.Table) -> list[Problem]:
    problems = []
    episodes = column_to_numpy(data.column("episode_index")).astype(np.int64)
    frames = column_to_numpy(data.column("frame_index")).astype(np.int64)
    arrays = {}
    for name, ft in info["features"].items():
        if not ft["dtype"].startswith("float") or name not in data.column_names:
            continue
        values = column_to_numpy(data.column(name)).reshape(data.num_rows, -1)
        arrays[name] = values
        bad_rows = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if len(bad_rows):
            where = _listed(f"episode {episodes[r]} frame {frames[r]}" for r in bad_rows)
            problems.append(Problem("values", f"column {name}", f"NaN or inf at {where}; drop those episodes with "
                                                                "`surrol-data filter` or re-record them"))
    same_episode = episodes[1:] == episodes[:-1]
    for now, nxt in _CHAINED:
        if now not in arrays or nxt not in arrays:
            continue
        differs = same_episode & ~np.isclose(arrays[nxt][:-1], arrays[now][1:], rtol=0, atol=1e-6,
                                             equal_nan=True).all(axis=1)
        if differs.any():
            rows = np.flatnonzero(differs)
            problems.append(Problem("values", f"column {nxt}", "differs from the next frame's " + now + " at " + _listed(
                f"episode {episodes[r]} frame {frames[r]}" for r in rows) + "; s_{t+1} must be the next s_t"))
    problems += _check_truncated(data, episodes, frames)
    return problems


def _check_truncated(data: pa.Table, episodes: np.ndarray, frames: np.ndarray) -> list[Problem]:
    """``next.truncated`` is true exactly on the last frame of an episode that ended without terminating."""
    if "next.truncated" not in data.column_names or "next.done" not in data.column_names:
        return []
    truncated = column_to_numpy(data.column("next.truncated")).reshape(-1).astype(bool)
    done = column_to_numpy(data.column("next.done")).reshape(-1).astype(bool)
    last = np.append(episodes[1:] != episodes[:-1], True)
    bad = np.flatnonzero(truncated != (last & ~done))
    if not len(bad):
        return []
    return [Problem("values", "column next.truncated", "must be true only on the last frame of an episode that "
                                                       "did not terminate (next.done false), at " + _listed(
        f"episode {episodes[r]} frame {frames[r]} (stored {bool(truncated[r])})" for r in bad)
                    + "; re-record the episode or rewrite the column")]


def _check_reward(side: dict, meta: pa.Table, data: pa.Table) -> list[Problem]:
    env_id = side.get("env_id")
    if not env_id and PROVENANCE_PREFIX + "env_id" in meta.column_names:
        env_ids = set(meta.column(PROVENANCE_PREFIX + "env_id").to_pylist())
        env_id = env_ids.pop() if len(env_ids) == 1 else None
    if not env_id:
        return [Problem("reward", SIDECAR_PATH, "no env id in the metadata: cannot check rewards against the task's "
                                                "compute_reward")]
    try:
        import gymnasium as gym

        import surrol_data.envs  # noqa: F401  (registers the ids)

        env = gym.make(env_id)
    except Exception as e:  # any failure to build the task is reported, not raised
        return [Problem("reward", f"env {env_id}", f"cannot be made ({type(e).__name__}: {e}); is the task "
                                                   "registered in surrol_data.envs?")]
    try:
        environment = column_to_numpy(data.column(NEXT_ENV_STATE)).reshape(data.num_rows, -1)
        achieved, desired = split_environment_state(environment)
        expected = np.asarray(env.unwrapped.compute_reward(achieved, desired, None), dtype=np.float32).reshape(-1)
    finally:
        env.close()
    reward = column_to_numpy(data.column("next.reward")).reshape(-1).astype(np.float32)
    bad = np.flatnonzero(~np.isclose(reward, expected, rtol=0, atol=1e-5))
    if not len(bad):
        return []
    episodes = column_to_numpy(data.column("episode_index"))
    frames = column_to_numpy(data.column("frame_index"))
    where = _listed(f"episode {episodes[r]} frame {frames[r]} (stored {reward[r]:g}, compute_reward "
                    f"{expected[r]:g})" for r in bad)
    return [Problem("reward", "column next.reward", f"inconsistent with {env_id}'s compute_reward(next achieved goal, "
                                                    f"desired goal) at {where}; the goals or rewards were altered, or "
                                                    "the task's reward changed since recording: re-record or relabel")]


def _check_lerobot(root: Path, info: dict) -> list[Problem]:
    from surrol_data.datasets.hub_offline import hub_offline, lerobot_root, usable_repo_id

    try:
        from surrol_data.datasets.writer import VIDEO_BACKEND, _lerobot_dataset_class

        from surrol_data.datasets.lerobot_compat import quick_parquet_load

        side = read_sidecar(root)
        with hub_offline(), quick_parquet_load():
            ds = _lerobot_dataset_class()(usable_repo_id(side.get("repo_id"), root), root=lerobot_root(root),
                                          video_backend=VIDEO_BACKEND)
        if ds.num_episodes != int(info["total_episodes"]) or ds.num_frames != int(info["total_frames"]):
            return [Problem("lerobot", str(root), f"LeRobotDataset sees {ds.num_episodes} episodes / {ds.num_frames} "
                                                  f"frames, info.json says {info['total_episodes']} / "
                                                  f"{info['total_frames']}; {REPAIR_HINT}")]
        if len(ds):
            ds[0]
            ds[len(ds) - 1]
    except Exception as e:  # whatever lerobot raises is the finding, but for the disk failing as it writes its cache
        from surrol_data.datasets.write_failure import disk_error

        refused = disk_error(e)
        if refused is not None:   # (the HF datasets cache under ~/.cache: the dataset itself may well be whole)
            raise refused from e
        return [Problem("lerobot", str(root), f"LeRobotDataset cannot read it: {type(e).__name__}: {e}")]
    return []

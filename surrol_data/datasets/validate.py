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
7. ``reward``: ``next.reward`` equals the task's ``compute_reward(next achieved goal, desired goal)`` (the env
   is made with ``gymnasium.make(env_id)`` from the dataset's metadata).
8. ``lerobot``: ``LeRobotDataset(repo_id, root=DIR)`` opens it offline and reads its first and last frame.

Each problem names the file / episode / column and says what to do.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import (
    DATA_DIR,
    EPISODES_DIR,
    DatasetError,
    column_to_numpy,
    load_info,
    parquet_files,
    unreadable_parquet_files,
)
from surrol_data.datasets.schema import (
    PROVENANCE_CHOICES,
    PROVENANCE_COLUMNS,
    PROVENANCE_PREFIX,
    SIDECAR_PATH,
    dims_from_features,
    frame_features,
)

REPAIR_HINT = "run `python -c \"from surrol_data.collect.recorder import repair; repair('DIR')\"`"
_MAX_LISTED = 5
_ARROW_TYPE_CHECK = {
    str: (pa.types.is_string, pa.types.is_large_string),
    bool: (pa.types.is_boolean,),
    int: (pa.types.is_integer,),
    float: (pa.types.is_floating,),
}
_CHAINED = (("observation.state", "next.observation.state"),
            ("observation.achieved_goal", "next.observation.achieved_goal"),
            ("observation.desired_goal", "next.observation.desired_goal"),
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


def validate_dataset(root: str | Path, *, check_reward: bool = True, check_lerobot: bool = True) -> list[Problem]:
    """All problems found in the dataset at ``root`` (empty list: it is valid). See the module docstring."""
    root = Path(root)
    problems: list[Problem] = []
    try:
        info = load_info(root)
    except DatasetError as e:
        return [Problem("format", str(root), str(e))]
    for path in unreadable_parquet_files(root):
        problems.append(Problem("parquet", str(path.relative_to(root)),
                                f"cannot be read (truncated, or no parquet footer: the recorder was killed before "
                                f"it finalized); {REPAIR_HINT} to keep every episode before the last checkpoint"))
    if problems:
        return problems
    if not parquet_files(root, EPISODES_DIR) or not parquet_files(root, DATA_DIR):
        return [Problem("format", str(root), f"no parquet files under {EPISODES_DIR}/ or {DATA_DIR}/: the dataset "
                                             "holds no episode; record at least one")]

    problems += _check_schema(info)
    if problems:
        return problems
    meta = pa.concat_tables([pq.read_table(p, columns=[n for n in pq.read_schema(p).names
                                                       if not n.startswith("stats/")])
                             for p in parquet_files(root, EPISODES_DIR)], promote_options="default")
    meta = meta.sort_by("episode_index")
    problems += _check_provenance(meta)
    data = _read_data(root, info)
    count_problems = _check_counts(info, meta, data)
    problems += count_problems
    if count_problems:
        return problems  # frame checks would only repeat the mismatch
    problems += _check_values(info, data)
    side = read_sidecar(root)
    if not side:
        problems.append(Problem("sidecar", SIDECAR_PATH, "missing or not JSON: dataset-level facts (task, env id) "
                                                         "are unknown; the dataset was not written by DatasetRecorder"))
    if check_reward:
        problems += _check_reward(side, meta, data)
    if check_lerobot:
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


def _read_data(root: Path, info: dict) -> pa.Table:
    names = [k for k, ft in info["features"].items() if ft["dtype"] not in ("video", "image", "string")]
    tables = []
    for path in parquet_files(root, DATA_DIR):
        present = [n for n in names if n in pq.read_schema(path).names]
        tables.append(pq.read_table(path, columns=present))
    return pa.concat_tables(tables, promote_options="default").sort_by("index")


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
    return problems


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
        achieved = column_to_numpy(data.column("next.observation.achieved_goal")).reshape(data.num_rows, -1)
        desired = column_to_numpy(data.column("next.observation.desired_goal")).reshape(data.num_rows, -1)
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
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    try:
        from surrol_data.collect.recorder import VIDEO_BACKEND, _lerobot_dataset_class

        side = read_sidecar(root)
        ds = _lerobot_dataset_class()(side.get("repo_id") or f"local/{root.name}", root=root,
                                      video_backend=VIDEO_BACKEND)
        if ds.num_episodes != int(info["total_episodes"]) or ds.num_frames != int(info["total_frames"]):
            return [Problem("lerobot", str(root), f"LeRobotDataset sees {ds.num_episodes} episodes / {ds.num_frames} "
                                                  f"frames, info.json says {info['total_episodes']} / "
                                                  f"{info['total_frames']}; {REPAIR_HINT}")]
        if len(ds):
            ds[0]
            ds[len(ds) - 1]
    except Exception as e:  # whatever lerobot raises is the finding
        return [Problem("lerobot", str(root), f"LeRobotDataset cannot read it: {type(e).__name__}: {e}")]
    return []

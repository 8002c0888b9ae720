"""``surrol-data upgrade DIR``: rewrite a dataset of an earlier surrol_data schema in the current one.

Schema 1 → 2 (see :mod:`surrol_data.datasets.schema`):

* ``observation.achieved_goal`` + ``observation.desired_goal`` become ``observation.environment_state``
  (achieved goal, then desired goal), and the same for ``next.observation.*``;
* ``next.truncated`` is added: true on the last frame of each episode that did not terminate;
* every dimension is named from the task (:func:`surrol_data.envs.names.dimension_names`; numbered names
  when the env cannot be made or its dimensions differ), and ``robot_type`` names the arms.

Values are moved, never recomputed: the per-episode and dataset statistics of the environment state are the
goals' statistics side by side (exact: the statistics are per dimension); only ``next.truncated`` gets new
statistics, from lerobot's own ``compute_episode_stats``. Each episode's ``provenance/content_hash`` is
recomputed over its new columns (the values are the same, the columns are not); every other provenance column,
the tasks, the device traces and the videos (hard-linked, not re-encoded) are kept. The dataset is rebuilt
beside the original and swapped in only once it validates, so an interrupted upgrade leaves the original.
"""

from __future__ import annotations

import ctypes
import errno
import glob
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from surrol_data.datasets import lerobot_compat
from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import (
    DATA_DIR,
    EPISODES_DIR,
    INFO_PATH,
    DatasetError,
    column_to_numpy,
    load_info,
    parquet_files,
)
from surrol_data.datasets.schema import (
    ENV_STATE,
    NEXT_ENV_STATE,
    PROVENANCE_COLUMNS,
    PROVENANCE_PREFIX,
    PROVENANCE_SEAL,
    SCHEMA1_GOAL_KEYS,
    SCHEMA_VERSION,
    SEAL_PREFIX,
    SIDECAR_PATH,
    content_hash,
    frame_features,
    is_schema1,
    package_version,
    provenance_seal,
    utc_now_iso,
    video_seal_column,
)

_LEROBOT_DEFAULT = ("timestamp", "frame_index", "episode_index", "index", "task_index")
_STATS_PATH = "meta/stats.json"
_PAIRS = {ENV_STATE: ("observation.achieved_goal", "observation.desired_goal"),
          NEXT_ENV_STATE: ("next.observation.achieved_goal", "next.observation.desired_goal")}


@dataclass
class UpgradeReport:
    root: Path
    from_version: int
    to_version: int = SCHEMA_VERSION
    episodes: int = 0
    frames: int = 0
    robot_type: str = ""
    names_from: str = ""   # the env whose names were used, or why numbered names were
    backup: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        return self.from_version != self.to_version

    def lines(self) -> list[str]:
        if not self.changed:
            return [f"{self.root} is already in schema {self.to_version}: nothing to do"]
        out = [f"{self.root}: schema {self.from_version} → {self.to_version}, {self.episodes} episodes, "
               f"{self.frames} frames",
               f"observation.environment_state = achieved goal + desired goal; next.truncated added; "
               f"dimension names from {self.names_from}; robot_type {self.robot_type}"]
        if self.backup is not None:
            out.append(f"the schema-{self.from_version} original is kept at {self.backup}")
        return out + self.notes


def schema_version_of(root: str | Path) -> int:
    """The surrol_data schema a dataset was written with (1 or :data:`SCHEMA_VERSION`)."""
    return 1 if is_schema1(load_info(root)["features"]) else SCHEMA_VERSION


def upgrade_dataset(root: str | Path, keep_backup: bool = False) -> UpgradeReport:
    """Rewrite the dataset at ``root`` in the current schema (see the module doc); a no-op when it already is."""
    from surrol_data.datasets.guard import ensure_finished
    from surrol_data.datasets.lock import DatasetLock

    given = Path(root)
    info = load_info(given)
    if not is_schema1(info["features"]):
        return UpgradeReport(given, from_version=SCHEMA_VERSION)
    ensure_finished(given)
    # The folder itself, not a symlink to it: the swap below renames folders, and renaming a link would put the
    # upgraded dataset where the link was and leave the original unchanged behind it.
    root = given.resolve()
    lock = DatasetLock(root)
    lock.acquire()  # held until the swap is done: no second upgrade of this dataset runs meanwhile
    try:
        report = UpgradeReport(given, from_version=1)
        removed = _remove_leftovers(root)
        if removed:
            report.notes.append(f"removed {len(removed)} leftover cop(ies) of an earlier, killed upgrade: "
                                + ", ".join(p.name for p in removed))
        work = root.parent / f"{_WORK_PREFIX.format(name=root.name)}{os.getpid()}"
        try:
            _build(root, work, info, report)
            problems = _validate(work)   # (a disk that fails while LeRobot reads the copy raises here)
        except BaseException:
            shutil.rmtree(work, ignore_errors=True)  # half a copy helps nobody; the original is untouched
            raise
        if problems:
            listed = "\n  ".join(problems)
            raise DatasetError(f"the upgraded copy of {given} does not validate, so the original is left as it was "
                               f"(the copy is at {work}):\n  {listed}")
        backup = root.parent / f"{root.name}.schema1"
        if backup.exists():
            raise DatasetError(f"{backup} already exists (an earlier upgrade's backup): move it away and run again; "
                               f"the upgraded copy is at {work}")
        original = _swap_in(work, root, backup)
    finally:
        lock.release()
    if keep_backup:
        if original != backup:
            os.replace(original, backup)
        report.backup = backup
    else:
        shutil.rmtree(original, ignore_errors=True)
    return report


def _swap_in(work: Path, root: Path, backup: Path) -> Path:
    """Put the upgraded ``work`` at ``root``; returns where the original is now. In one step where the system can
    (both moved or neither, whatever fails); else in two renames, the original put back if the second fails."""
    if _exchange(work, root):
        return work
    os.replace(root, backup)
    try:
        os.replace(work, root)
    except BaseException as e:
        try:
            os.replace(backup, root)
        except OSError:
            raise DatasetError(f"the upgraded copy could not be put in place ({e}), nor the original back: the original "
                               f"is kept, whole, at {backup}; move it back (`mv {backup} {root}`) once the disk takes "
                               f"changes again (the upgraded copy is at {work})") from e
        shutil.rmtree(work, ignore_errors=True)
        raise
    return backup


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 with RENAME_EXCHANGE); False, having changed nothing, where the
    system or its file system cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EXDEV):
        return False
    raise OSError(code, os.strerror(code), str(b))


_WORK_PREFIX = ".{name}.upgrade-"


def _remove_leftovers(root: Path) -> list[Path]:
    """The hidden copies that killed upgrades of ``root`` left beside it (called with ``root``'s lock held, so no
    upgrade of it is running: every such copy is a leftover, and the original was never touched)."""
    found = sorted(root.parent.glob(glob.escape(_WORK_PREFIX.format(name=root.name)) + "*"))
    for path in found:
        shutil.rmtree(path, ignore_errors=True)
    return found


def _validate(root: Path) -> list[str]:
    from surrol_data.datasets.validate import validate_dataset

    return [str(p) for p in validate_dataset(root, check_reward=False, check_lerobot=True)]


# ---------------------------------------------------------------------- building the new dataset


def _names(side: dict, dims: dict, report: UpgradeReport) -> dict:
    """frame_features' name arguments and the robot type, from the env the dataset was recorded in."""
    env_id = side.get("env_id", "")
    fallback = {"robot_type": "dvrk_psm" if dims["n_arms"] == 1 else f"dvrk_psm_x{dims['n_arms']}"}
    try:
        import gymnasium as gym

        import surrol_data.envs  # noqa: F401  (registers the ids)
        from surrol_data.envs.names import dimension_names

        env = gym.make(env_id)
        try:
            names = dimension_names(env)
            spaces = env.observation_space
            found = (spaces["observation"].shape[0], spaces["desired_goal"].shape[0], env.action_space.shape[0])
        finally:
            env.close()
    except Exception as e:  # noqa: BLE001 - any env that cannot be made means numbered names, said so
        report.names_from = f"numbers (the env {env_id!r} cannot be made: {type(e).__name__})"
        return fallback
    if found != (dims["obs_dim"], dims["goal_dim"], dims["act_dim"]):
        report.names_from = (f"numbers ({env_id} has dimensions {found}, the dataset "
                             f"{(dims['obs_dim'], dims['goal_dim'], dims['act_dim'])})")
        return fallback
    report.names_from = env_id
    return {"robot_type": names.robot_type, "state_names": names.state, "achieved_goal_names": names.achieved_goal,
            "desired_goal_names": names.desired_goal, "action_names": names.action}


def _schema1_dims(features: dict) -> dict:
    return {"obs_dim": int(features["observation.state"]["shape"][0]),
            "goal_dim": int(features["observation.desired_goal"]["shape"][0]),
            "act_dim": int(features["action"]["shape"][0]),
            "n_arms": int(features["complementary_info.jaw_angle"]["shape"][0]),
            "cameras": {k.removeprefix("observation.images."): tuple(int(v) for v in ft["shape"][:2])
                        for k, ft in features.items() if k.startswith("observation.images.")}}


def _link_or_copy(src: str, dst: str) -> str:
    try:
        os.link(src, dst)  # videos and traces are not rewritten: share the bytes
    except OSError:
        shutil.copy2(src, dst)
    return dst


def _build(root: Path, work: Path, info: dict, report: UpgradeReport) -> None:
    old = info["features"]
    dims = _schema1_dims(old)
    side = read_sidecar(root)
    named = _names(side, dims, report)
    report.robot_type = named.pop("robot_type")
    user = frame_features(dims["obs_dim"], dims["goal_dim"], dims["act_dim"], dims["n_arms"],
                          cameras=dims["cameras"] or None, **named)
    for key, ft in old.items():
        if ft["dtype"] == "video":
            user[key] = ft  # the encoder's "info" stays with the stream it describes
    features = {**user, **{k: old[k] for k in _LEROBOT_DEFAULT}}

    skip = {DATA_DIR, EPISODES_DIR.split("/")[0], ".surrol_data.lock"}
    work.mkdir()
    for item in root.iterdir():
        if item.name in skip:
            continue
        if item.is_dir():
            shutil.copytree(item, work / item.name, copy_function=_link_or_copy)
        else:
            shutil.copy2(item, work / item.name)
    (work / "meta").mkdir()
    for item in (root / "meta").iterdir():
        if item.name == "episodes":
            continue
        if item.is_dir():
            shutil.copytree(item, work / "meta" / item.name, copy_function=_link_or_copy)
        else:
            shutil.copy2(item, work / "meta" / item.name)

    hashes, truncated_stats = {}, {}
    # lerobot stores a shape-(1,) feature as a scalar column only when the shape is the tuple (1,), as at recording
    schema = lerobot_compat.hf_features({k: {**ft, "shape": tuple(ft["shape"])} for k, ft in features.items()}
                                        ).arrow_schema
    for path in parquet_files(root, DATA_DIR):
        table = _upgrade_data(pq.read_table(path), schema)
        target = work / path.relative_to(root)
        target.parent.mkdir(parents=True, exist_ok=True)
        episodes = column_to_numpy(table.column("episode_index"))
        with pq.ParquetWriter(target, table.schema) as writer:
            for ep in dict.fromkeys(episodes.tolist()):  # one row group per episode, as lerobot writes
                rows = table.filter(pc.equal(table.column("episode_index"), ep))
                writer.write_table(rows)
                frames = {k: column_to_numpy(rows.column(k)).reshape(rows.num_rows, -1)
                          for k, ft in user.items() if ft["dtype"] != "video"}
                hashes[int(ep)] = content_hash(frames, user)
                truncated_stats[int(ep)] = lerobot_compat.compute_episode_stats(
                    {"next.truncated": frames["next.truncated"]}, {"next.truncated": user["next.truncated"]})
                report.frames += rows.num_rows

    per_episode, sealed = [], True
    for path in parquet_files(root, EPISODES_DIR):
        table = _seal_episodes(work, info, _upgrade_episodes(pq.read_table(path), hashes, truncated_stats))
        sealed = sealed and PROVENANCE_SEAL in table.column_names
        target = work / path.relative_to(root)
        target.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, target)
        report.episodes += table.num_rows
        per_episode += [truncated_stats[int(e)] for e in column_to_numpy(table.column("episode_index"))]

    new_info = {**info, "features": features, "robot_type": report.robot_type}
    (work / INFO_PATH).write_text(json.dumps(new_info, indent=4))
    _upgrade_stats(root, work, per_episode)
    _upgrade_sidecar(work, side, new_info, report.robot_type, sealed)
    from surrol_data.datasets.card import write_dataset_card

    write_dataset_card(work)


def _concat_lists(a: pa.ChunkedArray, b: pa.ChunkedArray, dim: int) -> pa.Array:
    left = column_to_numpy(a).reshape(len(a), -1)
    right = column_to_numpy(b).reshape(len(b), -1)
    values = np.concatenate([left, right], axis=1).astype(np.float32)
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), pa.float32()), dim)


def _upgrade_data(table: pa.Table, schema: pa.Schema) -> pa.Table:
    columns = {name: table.column(name) for name in table.column_names}
    for new, (achieved, desired) in _PAIRS.items():
        dim = 2 * int(table.schema.field(achieved).type.list_size)
        columns[new] = _concat_lists(columns.pop(achieved), columns.pop(desired), dim)
    episodes = column_to_numpy(table.column("episode_index"))
    done = column_to_numpy(table.column("next.done")).reshape(-1).astype(bool)
    order = np.argsort(column_to_numpy(table.column("index")), kind="stable")
    last = np.zeros(len(episodes), bool)
    ordered = episodes[order]
    last[order] = np.append(ordered[1:] != ordered[:-1], True)
    columns["next.truncated"] = pa.array(last & ~done, pa.bool_())  # cast to next.done's storage below
    return pa.table({f.name: columns[f.name] for f in schema}).cast(schema)


def _upgrade_episodes(table: pa.Table, hashes: dict, truncated_stats: dict) -> pa.Table:
    names = table.column_names
    columns = {n: table.column(n) for n in names if not n.startswith("stats/")}
    stats: dict[str, pa.ChunkedArray | pa.Array] = {}
    for name in (n for n in names if n.startswith("stats/")):
        feature, stat = name.removeprefix("stats/").rsplit("/", 1)
        if feature in SCHEMA1_GOAL_KEYS:
            new = next(k for k, pair in _PAIRS.items() if feature in pair)
            if feature == _PAIRS[new][0]:  # the achieved goal's column brings the desired goal's beside it
                a = table.column(name).to_pylist()
                d = table.column(f"stats/{_PAIRS[new][1]}/{stat}").to_pylist()
                values = a if stat == "count" else [x + y for x, y in zip(a, d, strict=True)]
                stats[f"stats/{new}/{stat}"] = pa.array(values, table.schema.field(name).type)
            continue
        stats[name] = table.column(name)
        if feature == "next.done":
            episodes = column_to_numpy(table.column("episode_index")).astype(int)
            values = [np.asarray(truncated_stats[e]["next.truncated"][stat]).reshape(-1).tolist() for e in episodes]
            stats[f"stats/next.truncated/{stat}"] = pa.array(values, table.schema.field(name).type)
    if "provenance/content_hash" in columns:
        episodes = column_to_numpy(table.column("episode_index")).astype(int)
        columns["provenance/content_hash"] = pa.array([hashes[e] for e in episodes], pa.string())
    first_stat = next((i for i, n in enumerate(names) if n.startswith("stats/")), len(names))
    plain = [n for n in names if not n.startswith("stats/")]
    before = [n for n in plain if names.index(n) < first_stat]
    after = [n for n in plain if names.index(n) > first_stat]
    return pa.table({**{n: columns[n] for n in before}, **stats, **{n: columns[n] for n in after}})


def _seal_episodes(work: Path, info: dict, table: pa.Table) -> pa.Table:
    """``table`` with the seals the writer records (:mod:`surrol_data.datasets.seals`): each episode's provenance (its
    content hash is new) and its segment of every video (in ``work``, the upgraded copy). A table without every
    provenance column (a recording older than some of them) is left unsealed, as the writer leaves such a dataset."""
    from surrol_data.datasets.seals import segment_seal

    table = table.drop_columns([c for c in table.column_names if c.startswith(SEAL_PREFIX)])
    if any(PROVENANCE_PREFIX + name not in table.column_names for name in PROVENANCE_COLUMNS):
        return table
    columns = {name: table.column(PROVENANCE_PREFIX + name).to_pylist() for name in PROVENANCE_COLUMNS}
    seals = {PROVENANCE_SEAL: pa.array([provenance_seal({name: values[row] for name, values in columns.items()})
                                        for row in range(table.num_rows)], pa.string())}
    for key in (k for k, ft in info["features"].items() if ft["dtype"] == "video"):
        rows = table.select([c for c in table.column_names if c.startswith(f"videos/{key}/")]).to_pylist()
        seals[video_seal_column(key)] = pa.array([segment_seal(work, info["video_path"], key, row) for row in rows],
                                                 pa.string())
    # where the writer puts them: after the provenance columns, before the statistics
    names = table.column_names
    at = next((i for i, n in enumerate(names) if n.startswith("stats/")), len(names))
    return pa.table({**{n: table.column(n) for n in names[:at]}, **seals,
                     **{n: table.column(n) for n in names[at:]}})


def _upgrade_stats(root: Path, work: Path, truncated: list[dict]) -> None:
    path = root / _STATS_PATH
    if not path.exists():
        return
    stats = json.loads(path.read_text())
    for new, (achieved, desired) in _PAIRS.items():
        if achieved in stats and desired in stats:
            a, d = stats.pop(achieved), stats.pop(desired)
            stats[new] = {k: a[k] if k == "count" else list(a[k]) + list(d[k]) for k in a}
    if truncated:
        stats["next.truncated"] = {k: np.asarray(v).tolist()
                                   for k, v in lerobot_compat.aggregate_stats(truncated)["next.truncated"].items()}
    (work / _STATS_PATH).write_text(json.dumps(stats, indent=4))


def _upgrade_sidecar(work: Path, side: dict, info: dict, robot_type: str, sealed: bool) -> None:
    if not side:
        return
    side = dict(side)
    side.pop("seals", None)
    if sealed:
        side["seals"] = 1  # every episode carries seal/* columns now, as the writer's do
    side["upgrades"] = [*side.get("upgrades", []), {"from_schema": side.get("schema_version", 1),
                                                    "to_schema": SCHEMA_VERSION, "at": utc_now_iso(),
                                                    "package_version": package_version()}]
    side.update(schema_version=SCHEMA_VERSION, robot_type=robot_type)
    if isinstance(side.get("checkpoint"), dict):
        side["checkpoint"] = {**side["checkpoint"], "info": info}  # what repair falls back to
    (work / SIDECAR_PATH).write_text(json.dumps(side, indent=2, default=str))

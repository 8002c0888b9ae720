"""``surrol-data repair DIR``: make a dataset left by a killed writer (or damaged on disk) whole again.

What it keeps: every episode that is intact somewhere —

1. the longest run of episodes ``0..k-1`` whose metadata row, frames (and video files) are in readable
   files stays where it is (the files are cut back in place: cheap, whatever the dataset's size);
2. every later episode that is intact in a readable file (e.g. after a damaged *first* data file), and every
   episode in the recorder's journal (:mod:`surrol_data.datasets.journal`: the episodes finished since the
   last checkpoint), is written again after them through the dataset writer
   (:class:`~surrol_data.datasets.writer.DatasetWriter`), renumbered, with its provenance (and content hash) unchanged.

Everything else is reported as dropped, one reason per episode. Files that are moved out go to
``<root>/.surrol_data_repair/<time>/`` (delete it once satisfied), never deleted. Device traces are renamed
with their episodes. A dataset that is being written (its lock is held) is refused.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from surrol_data.datasets import journal
from surrol_data.datasets.card import write_dataset_card
from surrol_data.datasets.consolidate import finish_interrupted, interrupted, write_one_row_group_per_episode
from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.lock import DatasetLock, writer_pid
from surrol_data.datasets.reader import (
    DATA_DIR,
    EPISODES_DIR,
    INFO_PATH,
    DatasetError,
    parquet_files,
    trajectory_from_table,
)
from surrol_data.datasets.lerobot_compat import CREATE_STAGING
from surrol_data.datasets.schema import (CAMERA_VERSION, DEFAULT_CAMERA_RENDERER, PENDING_DATASET, PROVENANCE_COLUMNS,
                                         PROVENANCE_PREFIX, SIDECAR_PATH, camera_renderer_of, camera_version_of,
                                         utc_now_iso)

REPAIR_DIR = ".surrol_data_repair"
TRACE_DIR = "meta/device_traces"  # = surrol_data.collect.devices.trace.TRACE_DIR (not imported: no device deps)
_DEFAULT_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")


@dataclass
class RepairReport:
    episodes_kept: int = 0
    episodes_salvaged: int = 0           # of episodes_kept: re-written from a later file or the journal
    dropped: list[tuple[int, str]] = field(default_factory=list)  # (original episode index, why)
    moved: list[str] = field(default_factory=list)
    backup_dir: str | None = None
    frames: int = 0
    consolidation: str = ""              # what was done about an interrupted consolidation ("" if none was)

    @property
    def episodes_dropped(self) -> int:
        return len(self.dropped)

    def __getitem__(self, key):  # the dict-style access of the earlier API
        return getattr(self, key)

    def lines(self) -> list[str]:
        first = [self.consolidation] if self.consolidation else []
        if self.backup_dir is None:
            return first + [f"{'then nothing else' if first else 'nothing'} to repair: {self.episodes_kept} "
                            f"episodes, {self.frames} frames, every file readable"]
        out = first + [f"kept {self.episodes_kept} episodes ({self.frames} frames)"
               + (f", {self.episodes_salvaged} of them salvaged from later files or the journal"
                  if self.episodes_salvaged else "")]
        out += [f"dropped episode {ep}: {why}" for ep, why in self.dropped]
        if self.moved:
            out.append(f"moved {len(self.moved)} file(s) aside to {self.backup_dir} (delete it once satisfied)")
        return out


def _readable(path: Path) -> bool:
    try:
        pq.read_table(path)
        return True
    except Exception:  # noqa: BLE001 - any failure to read is "unreadable", which is what is reported
        return False


def _load_info(root: Path) -> dict:
    try:
        info = json.loads((root / INFO_PATH).read_text())
        if isinstance(info, dict) and "features" in info:
            return info
    except (OSError, json.JSONDecodeError):
        pass
    saved = read_sidecar(root).get("checkpoint", {}).get("info")
    if saved is None:
        raise DatasetError(f"{root / INFO_PATH} is missing or corrupt and {SIDECAR_PATH} holds no copy of it; "
                           "this dataset cannot be repaired automatically")
    return saved


def _video_ok(path: Path, until_s: float) -> bool:
    """The mp4 exists, opens, and its stream lasts until ``until_s`` (a truncated file ends early)."""
    if not path.exists():
        return False
    try:
        import av

        av.logging.set_level(av.logging.PANIC)  # a damaged file is the expected finding, not console noise
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            last = 0.0
            for packet in container.demux(stream):
                if packet.pts is not None:
                    last = max(last, float(packet.pts * stream.time_base))
            return last + 1.0 / 5 >= until_s - 1e-3  # the last frame starts one frame period before the end
    except Exception:  # noqa: BLE001
        return False


def is_unfinished(root: str | Path) -> list[str]:
    """Why ``root`` looks like it was left by a killed writer (empty list: it does not)."""
    root = Path(root)
    reasons = []
    for sub in (DATA_DIR, EPISODES_DIR):
        for path in parquet_files(root, sub):
            try:
                pq.read_metadata(path)
            except (pa.ArrowInvalid, OSError):
                reasons.append(f"{path.relative_to(root)} has no parquet footer")
    return killed_recording(root) + reasons


def killed_recording(root: str | Path) -> list[str]:
    """The signs that a recording of ``root`` was killed (empty: every recording of it finished): episodes in its
    journal, or a last session that never ended. Files damaged without these signs were damaged later (bit rot,
    a bad copy): the commands that read a dataset refuse those and leave the repair to the user."""
    root = Path(root)
    signs = []
    if journal.entries(root):
        signs.append(f"{len(journal.entries(root))} journal entr(ies) of episodes not yet in the dataset files")
    sessions = read_sidecar(root).get("sessions") or []
    if sessions and "ended_at" not in sessions[-1]:
        signs.append("its last recording session never ended")
    if interrupted(root):
        signs.append("the consolidation of its files was interrupted")
    if (root / journal.RENAMING).exists():
        signs.append("a repair of it was interrupted")
    return signs


def repair(root: str | Path) -> RepairReport:
    """Repair ``root`` in place (see the module doc); returns what was kept, dropped (and why) and moved."""
    root = Path(root)
    if not (root / "meta").is_dir():
        raise DatasetError(f"{root} is not a LeRobot dataset (no meta/ folder); nothing to repair")
    holder = writer_pid(root)
    if holder is not None:
        raise DatasetError(f"{root} is being written right now (pid {holder or '?'}); repair it only once the "
                           "writer has finished or died")
    with DatasetLock(root):
        finished = finish_interrupted(root)   # first: until it is done, a file may be out of its place
        journal.finish_renumbering(root)      # likewise a journal a stopped repair was renumbering
        _create_pending_dataset(root)
        report, salvage, info = _cut_back(root)
    report.consolidation = finished
    if salvage:
        _replay(root, info, salvage, report)
    sessions = read_sidecar(root).get("sessions") or []
    if report.backup_dir is not None or salvage or any("ended_at" not in s for s in sessions):
        _mark_sessions_ended(root, report)
        write_dataset_card(root)
    return report


def _create_pending_dataset(root: Path) -> None:
    """Create the LeRobot dataset of a recording killed before it did (it opened lazily: its sidecar holds the
    features, its journal every finished episode), as its recorder would have: then the repair goes on as for a
    recording killed before its first checkpoint (replaying the journal into the new dataset)."""
    from surrol_data.datasets.writer import VIDEO_BACKEND, _write_json_atomic

    side = read_sidecar(root)
    pending = side.get(PENDING_DATASET)
    if pending is None:
        return
    if not (root / INFO_PATH).exists():
        from surrol_data.datasets.hub_offline import hub_offline, usable_repo_id
        from surrol_data.datasets.lerobot_compat import create_dataset

        with hub_offline():
            create_dataset(root, repo_id=usable_repo_id(side.get("repo_id"), root), fps=int(pending["fps"]),
                           features=pending["features"], robot_type=pending.get("robot_type"), use_videos=True,
                           video_backend=VIDEO_BACKEND, metadata_buffer_size=1)
    shutil.rmtree(root / CREATE_STAGING, ignore_errors=True)   # a kill inside create_dataset's last steps
    side.pop(PENDING_DATASET)
    _write_json_atomic(root / SIDECAR_PATH, side)


def _cut_back(root: Path):
    info = _load_info(root)
    info_ok = (root / INFO_PATH).exists()
    try:
        json.loads((root / INFO_PATH).read_text())
    except (OSError, json.JSONDecodeError):
        info_ok = False
    stamp = time.strftime("%Y%m%dT%H%M%S")
    backup = root / REPAIR_DIR / stamp
    n = 0
    while backup.exists():  # never mix two repairs' files
        n += 1
        backup = root / REPAIR_DIR / f"{stamp}-{n}"
    report = RepairReport()

    def move_aside(path: Path) -> None:
        rel = path.relative_to(root)
        dest = backup / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(path), str(dest))
        report.moved.append(str(rel))

    bad_files: dict[str, str] = {}
    for sub in (DATA_DIR, EPISODES_DIR):
        for path in parquet_files(root, sub):
            if not _readable(path):
                bad_files[str(path.relative_to(root))] = "unreadable (truncated or corrupt)"
                move_aside(path)

    rows: dict[int, dict] = {}
    for path in parquet_files(root, EPISODES_DIR):
        for r in pq.read_table(path).to_pylist():
            rows.setdefault(int(r["episode_index"]), r)
    data_counts: Counter = Counter()
    readable_data: dict[tuple[int, int], Path] = {}
    for path in parquet_files(root, DATA_DIR):
        chunk, file = int(path.parent.name.split("-")[1]), int(path.stem.split("-")[1])
        readable_data[(chunk, file)] = path
        for ep, count in Counter(pq.read_table(path, columns=["episode_index"]).column(0).to_pylist()).items():
            data_counts[(chunk, file, int(ep))] += count

    features = info["features"]
    video_keys = [k for k, ft in features.items() if ft["dtype"] == "video"]
    video_checked: dict[str, bool] = {}

    def video_file(r: dict, key: str) -> str:
        return info["video_path"].format(video_key=key, chunk_index=r[f"videos/{key}/chunk_index"],
                                         file_index=r[f"videos/{key}/file_index"])

    def why_not_intact(ep: int) -> str | None:
        if ep not in rows:
            lost = [f for f in bad_files if f.startswith(EPISODES_DIR)]
            return ("its metadata row (provenance) was in " + ", ".join(lost) + ", which is unreadable"
                    if lost else "no metadata row for it in meta/episodes")
        r = rows[ep]
        where = (int(r["data/chunk_index"]), int(r["data/file_index"]))
        data_rel = info["data_path"].format(chunk_index=where[0], file_index=where[1])
        if where not in readable_data:
            return f"its frames were in {data_rel}, which is " + bad_files.get(data_rel, "missing")
        if data_counts[(*where, ep)] != int(r["length"]):
            return f"{data_rel} holds {data_counts[(*where, ep)]} of its frames, its metadata says {r['length']}"
        for key in video_keys:
            rel = video_file(r, key)
            if rel not in video_checked:
                ends = [float(x[f"videos/{key}/to_timestamp"]) for x in rows.values() if video_file(x, key) == rel]
                video_checked[rel] = _video_ok(root / rel, max(ends))
            if not video_checked[rel]:
                return f"its video {rel} is missing or truncated"
        return None

    known = set(rows) | {ep for (_, _, ep) in data_counts} | set(range(int(info.get("total_episodes", 0))))
    entries = dict(journal.entries(root))
    kept = 0
    while kept in rows and why_not_intact(kept) is None:
        kept += 1
    superseded = journal.renumbered_from(root)
    if superseded is not None:
        # a stopped repair renumbered the journal: from there on it holds the episodes, the files' copies go
        kept = min(kept, superseded)
        known = {ep for ep in known if ep < superseded}

    # Everything after the intact prefix: from the journal (exact arrays) or a readable file, else dropped.
    salvage: list[tuple[int, object]] = []
    video_episode_lost = []
    for ep in sorted(known | set(entries)):
        if ep < kept:
            continue
        if ep in entries:
            try:
                salvage.append((ep, journal.read_entry(entries[ep])))
                continue
            except ValueError as e:
                reason = str(e)
                if why_not_intact(ep) is not None:
                    report.dropped.append((ep, reason))
                    continue
        reason = why_not_intact(ep)
        if reason is not None:
            report.dropped.append((ep, reason))
        elif video_keys:
            video_episode_lost.append(ep)
            report.dropped.append((ep, "it comes after a damaged episode and camera frames cannot be copied out "
                                       "of the shared video file; re-record it"))
        else:
            salvage.append((ep, _from_files(root, info, rows[ep], readable_data)))

    salvage = _recordable(root, info, salvage, report)
    if salvage and any(ep != kept + i or ep not in entries for i, (ep, _) in enumerate(salvage)):
        # renumbered before any file is touched: see journal.renumber (the backup folder gets the old journal)
        journal.renumber(root, [(entries.get(ep), traj, prov) for ep, (traj, prov) in salvage], kept, backup)
        entries = {}

    frames_on_disk = sum(data_counts.values())
    kept_rows = [rows[i] for i in range(kept)]
    report.episodes_kept = kept
    report.frames = int(sum(int(r["length"]) for r in kept_rows))
    total_before = int(info.get("total_episodes", 0))
    nothing_wrong = (not report.moved and info_ok and kept == total_before and len(rows) == kept
                     and frames_on_disk == report.frames and not salvage and not report.dropped)
    if nothing_wrong:
        journal.drop_below(root, kept)  # stale entries of episodes already in the files
        return report, [], info
    report.backup_dir = str(backup)

    # Cut every surviving file back to episodes 0..kept-1.
    for sub, write in ((EPISODES_DIR, pq.write_table), (DATA_DIR, write_one_row_group_per_episode)):
        for path in parquet_files(root, sub):
            table = pq.read_table(path)
            keep = pc.less(table.column("episode_index"), kept)
            if pc.all(keep).as_py():
                continue
            filtered = table.filter(keep)
            tmp = path.with_name(path.name + ".tmp")
            if filtered.num_rows:
                try:
                    write(filtered, tmp)  # whole before the original moves: a full disk leaves the original
                except BaseException:
                    tmp.unlink(missing_ok=True)
                    raise
            move_aside(path)
            if filtered.num_rows:
                os.replace(tmp, path)
    referenced = {video_file(r, v) for r in kept_rows for v in video_keys}
    if (root / "videos").is_dir():
        for path in sorted((root / "videos").rglob("*.mp4")):
            if str(path.relative_to(root)) not in referenced:
                move_aside(path)
    if (root / "images").is_dir():  # PNG staging of the episode in progress
        move_aside(root / "images")
    # Device traces follow their episodes: salvaged ones are renamed when replayed, the rest moved aside.
    trace_dir = root / TRACE_DIR
    if trace_dir.is_dir():
        keep_traces = {ep for ep, _ in salvage}
        for path in sorted(trace_dir.glob("episode_*.npz*")):
            try:
                ep = int(path.name.split("_")[1].split(".")[0])
            except ValueError:
                ep = -1
            if ep >= kept and ep not in keep_traces or path.name.endswith(".tmp"):
                move_aside(path)
    if kept == 0:
        for name in ("meta/stats.json", "meta/tasks.parquet"):
            if (root / name).exists():
                move_aside(root / name)
    if not info_ok and (root / INFO_PATH).exists():
        move_aside(root / INFO_PATH)
    _rewrite_metadata(root, info, kept_rows)
    for ep, path in entries.items():  # replayed below or durable already: the journal is spent
        if ep < kept:
            path.unlink(missing_ok=True)
    return report, salvage, info


def _recordable(root: Path, info: dict, salvage: list, report: RepairReport) -> list:
    """The salvaged episodes the writer will take (the checks of its ``record``, made before anything is written:
    the journal is renumbered for exactly these); the others are dropped, with the writer's reason."""
    from surrol_data.datasets.schema import normalize_provenance
    from surrol_data.datasets.writer import DatasetWriter

    if not salvage:
        return salvage
    features = {k: v for k, v in info["features"].items() if k not in _DEFAULT_FEATURES}
    checker = DatasetWriter(root.parent / f".{root.name}.check-{os.getpid()}", features=features, task="check",
                            env_id="check", task_description="check", handle_signals=False)   # never opened
    ok = []
    for ep, (traj, provenance) in salvage:
        try:
            checker._frame_arrays(traj)
            normalize_provenance({k: v for k, v in provenance.items() if k in PROVENANCE_COLUMNS}, traj,
                                 defaults={"task": "check", "env_id": "check", "command": "", "git_commit": ""})
        except ValueError as e:
            report.dropped.append((ep, f"its saved copy cannot be recorded again ({e})"))
            continue
        ok.append((ep, (traj, provenance)))
    return ok


def _from_files(root: Path, info: dict, row: dict, readable_data: dict):
    path = readable_data[(int(row["data/chunk_index"]), int(row["data/file_index"]))]
    table = pq.read_table(path)
    table = table.filter(pc.equal(table.column("episode_index"), int(row["episode_index"]))).sort_by("frame_index")
    traj = trajectory_from_table(table, info["features"])
    provenance = {k: row.get(PROVENANCE_PREFIX + k) for k in PROVENANCE_COLUMNS}
    provenance = {k: v for k, v in provenance.items() if v is not None}
    return traj, provenance


def _replay(root: Path, info: dict, salvage: list, report: RepairReport) -> None:
    """Append the salvaged episodes through the writer (a fresh dataset when none was kept in place)."""
    from surrol_data.datasets.writer import DatasetWriter


    side = read_sidecar(root)
    features = {k: v for k, v in info["features"].items() if k not in _DEFAULT_FEATURES}
    task = side.get("task") or salvage[0][1][1].get("task", "unknown")
    env_id = side.get("env_id") or salvage[0][1][1].get("env_id", "unknown")
    description = side.get("task_description") or task
    kept = report.episodes_kept
    target = root if kept else root.parent / f".{root.name}.repair-{os.getpid()}"
    if not kept and target.exists():
        shutil.rmtree(target)  # our own leftover from an earlier repair that was itself killed
    renames = []
    recorder = DatasetWriter(target, features=None if kept else features, task=task, env_id=env_id,
                             task_description=description, append=bool(kept), repo_id=side.get("repo_id"),
                             robot_type=info.get("robot_type") or side.get("robot_type") or "dvrk_psm",
                             command=side.get("sessions", [{}])[-1].get("command", "surrol-data repair"),
                             handle_signals=False, checkpoint_every=10_000, checkpoint_interval_s=None, lazy=False,
                             camera_version=camera_version_of(side, features) or CAMERA_VERSION,
                             camera_renderer=camera_renderer_of(side, features) or DEFAULT_CAMERA_RENDERER)
    with recorder:
        for ep, (traj, provenance) in salvage:   # each passed the writer's checks (_recordable)
            provenance = {k: v for k, v in provenance.items() if k in PROVENANCE_COLUMNS}
            new = recorder.record(traj, provenance)
            renames.append((ep, new))
            report.frames += len(traj)
    if not kept:  # move the freshly written files into the dataset (its own versions were moved aside)
        for rel in ("data", "videos", "meta/episodes", "meta/info.json", "meta/stats.json", "meta/tasks.parquet"):
            src, dst = target / rel, root / rel
            if src.exists():
                if dst.is_dir():
                    shutil.rmtree(dst)
                elif dst.exists():
                    dst.unlink()
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(str(src), str(dst))
        shutil.rmtree(target, ignore_errors=True)
    trace_dir = root / TRACE_DIR
    for old, new in renames:  # old < new never happens (salvaged episodes only move down), so rename in order
        src = trace_dir / f"episode_{old:06d}.npz"
        if src.exists() and old != new:
            os.replace(src, trace_dir / f"episode_{new:06d}.npz")
    journal.drop_below(root, sys.maxsize)
    report.episodes_salvaged = len(renames)
    report.episodes_kept += len(renames)


def _mark_sessions_ended(root: Path, report: RepairReport) -> None:
    from surrol_data.datasets.writer import _write_json_atomic

    side = read_sidecar(root)
    now = utc_now_iso()
    for session in side.get("sessions", []):
        if "ended_at" not in session:
            session["ended_at"] = now
            session["interrupted"] = True
    side.setdefault("repairs", []).append({
        "at": now, "episodes_kept": report.episodes_kept, "episodes_salvaged": report.episodes_salvaged,
        "episodes_dropped": report.episodes_dropped,
        "dropped": [{"episode": ep, "why": why} for ep, why in report.dropped],
        "backup_dir": str(Path(report.backup_dir).relative_to(root)) if report.backup_dir else ""})
    _write_json_atomic(root / SIDECAR_PATH, side)


def _rewrite_metadata(root: Path, info: dict, kept_rows: list[dict]) -> None:
    """info.json totals, stats.json (re-aggregated from the kept episodes' stats) and tasks.parquet."""
    from surrol_data.datasets.writer import _write_json_atomic

    tasks: list[str] = []
    for r in kept_rows:
        tasks += [t for t in r["tasks"] if t not in tasks]
    tasks_path = root / "meta" / "tasks.parquet"
    try:
        existing = pq.read_table(tasks_path).to_pandas()
        names = list(existing.index if "task" not in existing.columns else existing["task"])
        task_ok = names[:len(tasks)] == tasks
    except Exception:  # noqa: BLE001 - missing or damaged: rewritten below
        task_ok = False
    if not task_ok and kept_rows:
        import pandas as pd

        # LeRobot assigns task indices in order of first appearance, which this reproduces.
        pd.DataFrame({"task_index": range(len(tasks))}, index=pd.Index(tasks, name="task")).to_parquet(tasks_path)

    info = dict(info)
    info["total_episodes"] = len(kept_rows)
    info["total_frames"] = int(sum(r["length"] for r in kept_rows))
    info["total_tasks"] = len(pq.read_table(tasks_path)) if kept_rows else 0
    info["splits"] = {"train": f"0:{len(kept_rows)}"}
    _write_json_atomic(root / INFO_PATH, info)

    episode_stats = []
    for r in kept_rows:
        stats: dict[str, dict] = {}
        for key, value in r.items():
            if key.startswith("stats/") and value is not None:
                _, feature, stat = key.split("/", 2)
                stats.setdefault(feature, {})[stat] = np.asarray(value)
        episode_stats.append(stats)
    if episode_stats:
        from surrol_data.datasets.lerobot_compat import aggregate_stats, write_stats

        write_stats(aggregate_stats(episode_stats), root)
    elif (root / "meta" / "stats.json").exists():
        (root / "meta" / "stats.json").unlink()

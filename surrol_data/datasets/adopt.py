"""``surrol-data adopt EDITED --from ORIGINAL``: take back a dataset that lerobot's own tools rewrote.

lerobot's ``aggregate_datasets`` and ``lerobot-edit-dataset`` (delete or split episodes, ...) write a valid LeRobot
dataset, but not all of ours: the data parquet goes through pandas (fixed-size vectors become lists), the edit
tools rebuild ``meta/episodes`` without the ``provenance/*`` and ``seal/*`` columns, and neither writes the
sidecar, the device traces or the card. Adoption restores them *by episode identity*: each episode of EDITED is
found in ORIGINAL by the content hash of its frames (the same frames give the same hash), and gets that episode's
provenance, provenance seal and device trace; the data files are cast back to ORIGINAL's exact schema; the video
seals are computed again from EDITED's videos (lerobot's tools may have re-encoded them); the sidecar says where
each episode came from (``derived_from``), and the card is written. An episode whose frames match no episode of
ORIGINAL is refused before anything is written: adoption restores what lerobot kept, it does not vouch for
frames that changed.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.repair import TRACE_DIR
from surrol_data.datasets.reader import (
    DATA_DIR,
    EPISODES_DIR,
    INFO_PATH,
    DatasetError,
    DatasetReader,
    column_to_numpy,
    load_info,
    parquet_files,
)
from surrol_data.datasets.schema import (
    PROVENANCE_PREFIX,
    PROVENANCE_SEAL,
    SIDECAR_PATH,
    content_hash,
    utc_now_iso,
    video_seal_column,
)

_LEROBOT_DEFAULT = ("timestamp", "frame_index", "episode_index", "index", "task_index")


@dataclass
class AdoptReport:
    episodes: int
    source_episodes: list[int]  # for each episode of EDITED, its index in its ORIGINAL
    sources: list[str] | None = None   # the ORIGINALs, as given
    source_of: list[int] | None = None  # for each episode of EDITED, which ORIGINAL (an index into sources)

    def lines(self) -> list[str]:
        if not self.sources or len(self.sources) == 1:
            return [f"adopted {self.episodes} episodes; their provenance, seals, device traces, sidecar and card "
                    f"restored from the original's episodes {_ranges(self.source_episodes)}"]
        return [f"adopted {self.episodes} episodes; their provenance, seals, device traces, sidecar and card "
                f"restored from {len(self.sources)} originals:"] + [
            f"  {name}: episodes {_ranges([e for e, i in zip(self.source_episodes, self.source_of) if i == k])}"
            for k, name in enumerate(self.sources) if k in self.source_of]


def _ranges(indices: list[int]) -> str:
    return ", ".join(str(i) for i in indices[:20]) + (f" (+{len(indices) - 20} more)" if len(indices) > 20 else "")


def _user_features(info: dict) -> dict:
    return {k: v for k, v in info["features"].items() if k not in _LEROBOT_DEFAULT}


def adopt(edited: str | Path, original: str | Path | list) -> AdoptReport:
    """Restore our metadata in ``edited`` from ``original`` — one dataset, or several (``aggregate_datasets`` of
    them: each episode is found in whichever holds its frames) — see the module doc; DatasetError if it cannot be."""
    from surrol_data.datasets.guard import require_dataset_folder, require_valid
    from surrol_data.datasets.merge import _point_episode_rows_at_their_files, _restore_frame_types

    edited = Path(edited)
    require_dataset_folder(edited)
    originals = list(original) if isinstance(original, (list, tuple)) else [original]
    sources = [require_valid(o) for o in originals]
    info = load_info(edited)
    features = _user_features(load_info(sources[0]))
    for named, source in zip(originals, sources, strict=True):
        theirs = _user_features(load_info(source))
        differ = sorted(k for k in set(theirs) | set(_user_features(info))
                        if (theirs.get(k) or {}).get("dtype") != (info["features"].get(k) or {}).get("dtype")
                        or list((theirs.get(k) or {}).get("shape", [])) != list((info["features"].get(k) or {})
                                                                                 .get("shape", [])))
        if differ:
            raise DatasetError(f"{edited} is not an edit of {named}: features differ in {differ}; nothing was "
                               "changed")
    matches = _match_episodes(edited, features, [DatasetReader(s) for s in sources])

    _restore_frame_types(edited, sources[0])
    _point_episode_rows_at_their_files(edited)
    _restore_episode_columns(edited, sources, info, matches)
    _restore_traces(edited, sources, matches)
    _write_sidecar(edited, sources, originals, matches)
    from surrol_data.datasets.card import write_dataset_card

    write_dataset_card(edited)
    ordered = [matches[ep] for ep in sorted(matches)]
    return AdoptReport(episodes=len(ordered), source_episodes=[ep for _, ep in ordered],
                       sources=[str(o) for o in originals], source_of=[i for i, _ in ordered])


def _match_episodes(edited: Path, features: dict, originals: list[DatasetReader]) -> dict[int, tuple[int, int]]:
    """EDITED episode index -> (which ORIGINAL, its episode index), by the content hash of the frames."""
    by_hash = {h: (i, int(e)) for i, original in enumerate(originals)
               for h, e in zip(original.episodes["content_hash"], original.episodes["episode_index"], strict=True)}
    names = [k for k, ft in features.items() if ft["dtype"] not in ("video", "image", "string")]
    tables = []
    for path in parquet_files(edited, DATA_DIR):
        try:
            tables.append(pq.read_table(path, columns=["episode_index", "frame_index", *names]))
        except Exception as e:  # noqa: BLE001 - unreadable or missing columns: not an edit we can adopt
            raise DatasetError(f"{path} cannot be read as the original's frames ({type(e).__name__}: {e}); "
                               "nothing was changed") from None
    if not tables:
        raise DatasetError(f"{edited} holds no data file; nothing to adopt")
    data = pa.concat_tables(tables, promote_options="default").sort_by([("episode_index", "ascending"),
                                                                         ("frame_index", "ascending")])
    episodes = column_to_numpy(data.column("episode_index")).astype(np.int64)
    matches, unmatched = {}, []
    for ep in np.unique(episodes):
        rows = np.flatnonzero(episodes == ep)
        part = data.slice(int(rows[0]), len(rows))
        frames = {k: column_to_numpy(part.column(k)).reshape(part.num_rows, -1) for k in names}
        found = by_hash.get(content_hash(frames, features))
        if found is None:
            unmatched.append(int(ep))
        else:
            matches[int(ep)] = found
    if unmatched:
        listed = ", ".join(map(str, unmatched[:10])) + (" ..." if len(unmatched) > 10 else "")
        named = " or ".join(str(o.root) for o in originals)
        raise DatasetError(f"episode(s) {listed} of {edited} match no episode of {named} (their frames differ "
                           "from every recorded episode): adopt restores what lerobot's tools kept, not changed "
                           "frames; nothing was changed")
    return matches


def _restore_episode_columns(edited: Path, sources: list[Path], info: dict, matches: dict[int, tuple[int, int]]
                             ) -> None:
    from surrol_data.datasets.seals import segment_seal

    tables = []
    for i, source in enumerate(sources):   # every original's episode rows, each marked with its original
        table = pa.concat_tables([pq.read_table(p) for p in parquet_files(source, EPISODES_DIR)],
                                 promote_options="default")
        tables.append(table.append_column("_original", pa.array([i] * table.num_rows, pa.int64())))
    theirs = pa.concat_tables(tables, promote_options="default")
    carried = [c for c in theirs.column_names if c.startswith(PROVENANCE_PREFIX) or c == PROVENANCE_SEAL]
    row_of = {(int(i), int(e)): r for r, (i, e) in enumerate(zip(theirs.column("_original").to_pylist(),
                                                                 theirs.column("episode_index").to_pylist()))}
    video_keys = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
    for path in parquet_files(edited, EPISODES_DIR):
        table = pq.read_table(path)
        table = table.drop_columns([c for c in table.column_names if c.startswith((PROVENANCE_PREFIX, "seal/"))])
        rows = [row_of[matches[int(e)]] for e in table.column("episode_index").to_pylist()]
        for column in carried:
            values = theirs.column(column).take(pa.array(rows, pa.int64()))
            table = table.append_column(theirs.schema.field(column), values)
        for key in video_keys:
            seals = [segment_seal(edited, info["video_path"], key, r)
                     for r in table.select([c for c in table.column_names if c.startswith(f"videos/{key}/")]).to_pylist()]
            table = table.append_column(video_seal_column(key), pa.array(seals, pa.string()))
        tmp = path.with_name(path.name + ".tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, path)


def _restore_traces(edited: Path, sources: list[Path], matches: dict[int, tuple[int, int]]) -> None:
    for ep, (i, src) in matches.items():
        trace = sources[i] / TRACE_DIR / f"episode_{src:06d}.npz"
        if trace.exists():
            dst = edited / TRACE_DIR / f"episode_{ep:06d}.npz"
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(trace, dst)


def _write_sidecar(edited: Path, sources: list[Path], originals: list, matches: dict[int, tuple[int, int]]) -> None:
    from surrol_data.datasets.hub_offline import local_repo_id
    from surrol_data.datasets.writer import _write_json_atomic

    roots = [str(Path(o).resolve()) for o in originals]
    side = read_sidecar(sources[0])
    now = utc_now_iso()
    side.update({"repo_id": local_repo_id(edited), "updated_at": now,
                 "checkpoint": {"at": now, "episodes": len(matches),
                                "info": json.loads((edited / INFO_PATH).read_text())},
                 "derived_from": {"operation": "adopt", "where": "", "duplicates_dropped": [],
                                  "method": "edited by lerobot's own tools, adopted by episode content hash",
                                  "sources": [{"root": root, "episodes": len(DatasetReader(source))}
                                              for root, source in zip(roots, sources, strict=True)],
                                  "episodes": [{"episode": ep, "source_root": roots[i], "source_episode": src}
                                               for ep, (i, src) in sorted(matches.items())]}})
    _write_json_atomic(edited / SIDECAR_PATH, side)

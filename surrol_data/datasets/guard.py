"""What every command does before it trusts a dataset it was given.

0. :func:`require_dataset_folder`: a path that does not exist, or is no dataset folder at all, is said to be so.
1. :func:`ensure_finished`: a dataset left by a killed recording (its journal holds episodes, or its last session
   never ended) is repaired automatically, saying so on stderr (the same as ``surrol-data repair DIR``); one on a
   disk this process cannot write is repaired in a temporary view instead (:mod:`readonly_view`), never in place.
   A *finished* dataset whose files are damaged (bit rot, a bad copy) is refused with the repair command to run:
   reading never modifies what is read. One being written by a live process is refused.
2. :func:`require_valid`: the cheap checks of :func:`surrol_data.datasets.validate.validate_dataset` (no env,
   no lerobot import, videos only demuxed); a damaged dataset is refused with the validator's own messages. A
   dataset whose bytes already passed them is not checked again (:mod:`validated_cache`: by content digest).
   ``info``, which shows metadata only, asks for the metadata checks only (``frames=False``): no frame is read;
   it remembers its whole answer by content digest (:mod:`info_cache`), so the same bytes are not checked twice.

Both return the folder to read: the dataset itself, or the repaired view of a read-only one.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from surrol_data.datasets.reader import DatasetError


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def ensure_finished(root: str | Path, notify: Callable[[str], None] = _stderr) -> Path:
    """Repair ``root`` if a killed recording left it unfinished (see the module doc); the folder to read."""
    from surrol_data.datasets.lock import writer_pid
    from surrol_data.datasets.repair import killed_recording, repair

    root = Path(root)
    if not (root / "meta").is_dir():
        return root  # not a dataset: the caller's own check says so
    holder = writer_pid(root)
    if holder is not None:
        raise DatasetError(f"{root} is being written by another process (pid {holder or '?'}); wait until it "
                           "has finished")
    reasons = killed_recording(root) + [f"{path.relative_to(root)} has no parquet footer"
                                        for path in _footerless(root)]
    if not reasons:
        return root
    killed = killed_recording(root)
    if not killed:
        raise DatasetError(f"{root} was damaged after its recording finished ({'; '.join(reasons)}); nothing was "
                           f"changed: run `surrol-data repair {root}` to keep its intact episodes")
    from surrol_data.datasets.readonly_view import is_writable, writable_view

    target = root
    if not is_writable(root):
        target = writable_view(root)
        notify(f"{root} was left unfinished by a killed recording ({'; '.join(killed)}) and cannot be written "
               f"here: reading a repaired copy of it (in {target.parent}; the dataset is not changed; "
               f"`surrol-data repair {root}` on a writable copy keeps the repair)")
    else:
        notify(f"{root} was left unfinished by a killed recording ({'; '.join(killed)}): repairing it "
               f"(`surrol-data repair {root}`)")
    report = repair(target)
    for line in report.lines():
        notify(f"  repair: {line}")
    return target


def _footerless(root: Path) -> list[Path]:
    """Data / episodes parquet files that do not end in a parquet footer (cut short). Only the file's last 8 bytes
    are read — parsing every footer cost seconds at 10,000 episodes; a footer damaged inside is found by the
    checks that read the file."""
    from surrol_data.datasets.reader import DATA_DIR, EPISODES_DIR, parquet_files

    bad = []
    for sub in (DATA_DIR, EPISODES_DIR):
        for path in parquet_files(root, sub):
            try:
                with open(path, "rb") as fh:
                    size = fh.seek(0, 2)
                    fh.seek(max(size - 8, 0))
                    tail = fh.read(8)
                ok = size >= 12 and tail[4:] == b"PAR1" and int.from_bytes(tail[:4], "little") <= size - 12
            except OSError:
                ok = False
            if not ok:
                bad.append(path)
    return bad


def require_dataset_folder(root: str | Path) -> None:
    """DatasetError unless ``root`` is a folder with a ``meta/`` folder: a path that is not there (a typo, a
    dataset not recorded yet) is not "damaged", and ``repair`` cannot help it."""
    root = Path(root)
    if not root.exists():
        raise DatasetError(f"{root} does not exist: check the path, or record a dataset there with "
                           f"`surrol-data collect --source script --task NeedlePick --num-episodes 10 --out {root}`")
    if not root.is_dir():
        raise DatasetError(f"{root} is a file: give the dataset's folder (the one that holds meta/ and data/)")
    if not (root / "meta").is_dir():
        raise DatasetError(f"{root} is not a dataset (it has no meta/ folder): give the dataset's folder, the one "
                           "that holds meta/ and data/")


def require_valid(root: str | Path, notify: Callable[[str], None] = _stderr, *, frames: bool = True) -> Path:
    """:func:`require_dataset_folder`, :func:`ensure_finished`, then the cheap validation checks; DatasetError
    listing every problem found. Returns the folder to read (see :func:`ensure_finished`).

    ``frames=False`` (a command that shows the metadata only, ``info``): the checks of everything but the frames
    (:func:`~surrol_data.datasets.validate.validate_dataset` with ``frames=False``: provenance and its seals,
    counts, footers ...), run every time — they read no frame and hash nothing, so they stay fast at any size.
    With frames, a dataset whose bytes already passed is not checked again (by content digest)."""
    require_dataset_folder(root)
    return check_finished(root, ensure_finished(root, notify), frames=frames)


def check_finished(root: str | Path, target: Path, *, frames: bool = True) -> Path:
    """The checks of :func:`require_valid` on ``target``, what :func:`ensure_finished` returned for ``root`` (the
    folder the user named, which the messages name); ``target``."""
    from surrol_data.datasets.validate import validate_dataset
    from surrol_data.datasets.validated_cache import dataset_digest, known_valid, remember_valid

    if frames:
        digest = dataset_digest(target)
        if known_valid(digest):   # these very bytes passed these very checks before
            return target
    problems = validate_dataset(target, check_reward=False, check_lerobot=False, frames=frames)
    if frames and not problems:
        remember_valid(digest)
    if problems:
        if rewritten_by_lerobot(target):   # not damaged: lerobot's tools kept the frames, not our metadata
            raise DatasetError(adopt_hint(root))
        listed = "\n  ".join(str(p) for p in problems)
        raise DatasetError(f"{root} is damaged ({len(problems)} problem(s)); nothing was done:\n  {listed}\n"
                           f"Run `surrol-data validate {root}` for the full check, `surrol-data repair {root}` "
                           "to keep its intact episodes.")
    return target


def rewritten_by_lerobot(root: str | Path) -> bool:
    """Whether ``root`` is a LeRobot dataset that lerobot's own tools wrote (``lerobot-edit-dataset``,
    ``aggregate_datasets``) from ours: its info.json and frames are there, our sidecar or the episodes' provenance
    columns are not — what ``surrol-data adopt`` restores (``repair`` keeps episodes; it has none to drop here)."""
    import pyarrow.parquet as pq

    from surrol_data.datasets.reader import EPISODES_DIR, INFO_PATH, parquet_files
    from surrol_data.datasets.schema import PROVENANCE_PREFIX, SIDECAR_PATH

    import json

    root = Path(root)
    try:
        features = json.loads((root / INFO_PATH).read_text()).get("features", {})
    except (OSError, ValueError):
        return False
    if "complementary_info.tip_position" not in features:   # not made from one of ours (our frames hold the tip)
        return False
    if not (root / SIDECAR_PATH).is_file():
        return True
    try:
        files = parquet_files(root, EPISODES_DIR)
        return bool(files) and not any(n.startswith(PROVENANCE_PREFIX) for n in pq.read_schema(files[0]).names)
    except Exception:  # noqa: BLE001 - an unreadable episodes file is damage, for the caller's message to say
        return False


def adopt_hint(root: str | Path) -> str:
    return (f"{root} was rewritten by lerobot's own tools (lerobot-edit-dataset, aggregate_datasets): its frames are "
            "there, our provenance, sidecar and device traces are not. Take it back with `surrol-data adopt "
            f"{root} --from ORIGINAL` (repeat --from for each dataset it was made from); nothing was done")

"""A write the disk refused (full, over quota, read-only, an I/O error, no permission), said in one line: which
failure, and what is kept.

Every writing command stops at the first such failure and says so with :func:`describe` and :func:`what_is_kept`.
What is kept follows from how the writers write (:mod:`surrol_data.datasets.writer`): an episode is in the journal
before ``record`` returns and leaves it only once it is in closed files that the sidecar's checkpoint counts, and a
session whose write failed is left as a killed recording, which every command repairs first. So the episodes kept
are the checkpoint's plus the journal's later entries, whatever call failed; ``benchmarks/crash_safety.py
--faults`` fails each call of every writing path in turn and checks that this count is what the dataset holds.
"""

from __future__ import annotations

import errno
import json
from pathlib import Path

# errno -> what it means for the user, and what to do before running the command again
_KINDS = {
    errno.ENOSPC: ("no space left on the disk", "free some space"),
    errno.EDQUOT: ("the disk quota is exceeded", "free some space"),
    errno.EFBIG: ("a file grew past what the disk allows", "record into a folder on another disk"),
    errno.EROFS: ("the disk is read-only", "make the disk writable (or copy the dataset to a writable one)"),
    errno.EIO: ("the disk reported an I/O error", "check the disk (dmesg, its mount)"),
    errno.EACCES: ("no permission to write", "get write permission to the folder"),
    errno.EPERM: ("no permission to write", "get write permission to the folder"),
}
# what pyarrow and ffmpeg put in their messages when they pass on a failed call without its errno
_MESSAGES = {"No space left on device": errno.ENOSPC, "Disk quota exceeded": errno.EDQUOT,
             "Read-only file system": errno.EROFS, "Input/output error": errno.EIO, "File too large": errno.EFBIG}


def disk_error(error: BaseException | None) -> OSError | None:
    """The OSError behind ``error`` (itself or one it was raised from) when it is one of the disk's refusals above;
    None otherwise. One wrapped without its errno (pyarrow's, ffmpeg's) is recognised by its message."""
    seen = 0
    while error is not None and seen < 20:
        if isinstance(error, OSError):
            if error.errno in _KINDS:
                return error
            for text, code in _MESSAGES.items():
                if text in str(error):
                    return OSError(code, text, getattr(error, "filename", None))
        error, seen = error.__cause__ or error.__context__, seen + 1
    return None


def describe(error: OSError) -> str:
    """``no space left on the disk (ENOSPC)``: what the failure was."""
    what, _ = _KINDS.get(error.errno, (error.strerror or str(error), ""))
    return f"{what} ({errno.errorcode.get(error.errno, error.errno)})"


def remedy(error: OSError) -> str:
    return _KINDS.get(error.errno, ("", "fix the disk"))[1]


def episodes_kept(root: str | Path) -> tuple[int, int]:
    """(episodes in the dataset's closed files, by its sidecar's last checkpoint; episodes in its journal after
    them): together, every episode a stopped writer of ``root`` finished."""
    from surrol_data.datasets import journal
    from surrol_data.datasets.schema import SIDECAR_PATH

    root = Path(root)
    try:
        side = json.loads((root / SIDECAR_PATH).read_text())
        in_files = int(side.get("checkpoint", {}).get("episodes", 0))
        sessions = side.get("sessions") or []
        if sessions and "ended_at" in sessions[-1]:   # finished: info.json counts them
            in_files = int(json.loads((root / "meta" / "info.json").read_text())["total_episodes"])
    except (OSError, ValueError, KeyError, TypeError):
        in_files = 0
    first = journal.renumbered_from(root)
    in_journal = len([i for i, _ in journal.entries(root) if i >= (in_files if first is None else first)])
    if first is not None:
        in_files = min(in_files, first)
    return in_files, in_journal


def what_is_kept(root: str | Path, error: OSError, *, inputs: str = "") -> str:
    """What a stopped writer of the dataset ``root`` left, and how to go on (``inputs``: a sentence about the
    command's inputs, e.g. that they are unchanged)."""
    root = Path(root)
    then = f"{remedy(error)}, then"
    if not (root / "meta").is_dir():
        return (f"nothing was written to {root}{'; ' + inputs if inputs else ''}. To go on: {then} run the command "
                "again")
    in_files, in_journal = episodes_kept(root)
    held = in_files + in_journal
    where = f" ({in_files} in its files, {in_journal} in its journal)" if in_journal else ""
    return (f"every episode finished is kept: {held} in {root}{where}{'; ' + inputs if inputs else ''}. To go on: "
            f"{then} run `surrol-data repair {root}` (every command that opens it repairs it first)")

"""A writable stand-in for a dataset that cannot be written (a read-only mount, a folder without write permission).

A recording killed on a disk that is read-only now (a finished share, an archive mounted read-only) still needs
its repair (the journal's episodes replayed, the footer-less files cut back) before anyone can read it, and the
repair must not write into the folder. :func:`writable_view` builds, in a temporary folder, a view of the
dataset: the small metadata files (``meta/`` without the device traces, the card) are copied, because the
repair rewrites them; the frames, videos, traces and journal entries are symbolic links, because the repair only
reads them, moves them aside (the link moves) or writes new files beside them. The view is repaired instead of
the dataset and read in its place; it is deleted when the process exits.
"""

from __future__ import annotations

import atexit
import errno
import os
import shutil
import tempfile
from pathlib import Path

from surrol_data.datasets.lock import LOCK_NAME

_LINKED_UNDER_META = "meta/device_traces/"


def is_writable(root: str | Path) -> bool:
    """Whether this process can create files in ``root`` (probed, as the lock would: a read-only mount refuses
    even root, whatever the permission bits say)."""
    probe = Path(root) / f".surrol_data_write_probe.{os.getpid()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as e:
        if e.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
            return False
        raise
    os.close(fd)
    probe.unlink()
    return True


_VIEWS: dict[Path, Path] = {}   # dataset -> its repaired view, made by this process


def view_of(root: str | Path) -> Path | None:
    """The view :func:`writable_view` made of ``root`` in this process (None if none): what to read for it, e.g. its
    info.json when the dataset itself has none yet (a recording killed before it created its LeRobot files)."""
    return _VIEWS.get(Path(root).resolve())


def writable_view(root: str | Path) -> Path:
    """A temporary, writable view of ``root`` (see the module doc), named like it; removed at exit."""
    root = Path(root).resolve()
    parent = Path(tempfile.mkdtemp(prefix="surrol_data_view_"))
    atexit.register(shutil.rmtree, parent, True)
    view = parent / root.name
    for folder, dirs, files in os.walk(root):
        here = Path(folder)
        rel = here.relative_to(root)
        (view / rel).mkdir(parents=True, exist_ok=True)
        for name in files:
            path_rel = (rel / name).as_posix()
            if name == LOCK_NAME and rel == Path("."):
                continue
            copied = path_rel == "README.md" or (path_rel.startswith("meta/")
                                                 and not path_rel.startswith(_LINKED_UNDER_META))
            if copied:
                shutil.copy2(here / name, view / rel / name)
            else:
                os.symlink(here / name, view / rel / name)
    _VIEWS[root] = view
    return view

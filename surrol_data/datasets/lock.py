"""One writer per dataset: an advisory ``flock`` on ``<root>/.surrol_data.lock``.

The kernel releases the lock when the holding process ends, however it ends (SIGKILL included), so a
held lock always means a live writer and a free lock on an unfinished dataset means a killed one (then
:func:`surrol_data.datasets.repair.repair` may run).
"""

from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path

from surrol_data.datasets.reader import DatasetError

LOCK_NAME = ".surrol_data.lock"


class DatasetLock:
    """Exclusive, non-blocking lock of a dataset folder; :meth:`acquire` raises DatasetError if it is held."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self._fd: int | None = None

    def acquire(self) -> DatasetLock:
        path = self.root / LOCK_NAME
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            if e.errno not in (errno.EROFS, errno.EACCES, errno.EPERM):
                raise
            raise DatasetError(f"{self.root} cannot be written here ({e.strerror}): a read-only disk or folder; "
                               "commands that only read it work, to change it copy it to a writable folder") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_pid(fd)
            os.close(fd)
            raise DatasetError(f"{self.root} is being written by another process{f' (pid {holder})' if holder else ''}: "
                               "two writers would interleave its files. Wait for it to finish, or write into "
                               "another folder and `surrol-data merge` them afterwards") from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    def __enter__(self) -> DatasetLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _read_pid(fd: int) -> str:
    try:
        return os.pread(fd, 32, 0).decode().strip()
    except OSError:
        return ""


def writer_pid(root: str | Path) -> str | None:
    """The pid of the live process writing ``root`` ("" if unknown), or None when nobody holds the lock."""
    path = Path(root) / LOCK_NAME
    if not path.exists():
        return None
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        pid = _read_pid(fd)
        os.close(fd)
        return pid
    fcntl.flock(fd, fcntl.LOCK_UN)
    os.close(fd)
    return None

"""Make the file-system calls of a run fail on purpose, one at a time: what ``benchmarks/crash_safety.py --faults`` and
``tests/test_write_faults.py`` run every writing command under (SQLite's I/O-error testing, in Python).

:class:`FaultInjector` wraps, for the duration of a ``with`` block, every call through which our code and the
libraries it writes with (lerobot, pyarrow, numpy, h5py, PyAV) change the disk: ``open`` for writing (and each
``write`` / ``flush`` of the file it returns), ``os.open`` for writing, ``os.write``, ``os.ftruncate``,
``os.sendfile``, ``os.fsync``, ``os.replace`` / ``os.rename``, ``os.mkdir``, ``os.unlink`` / ``os.remove``,
``os.rmdir``, ``os.link`` / ``os.symlink``, pyarrow's ``ParquetWriter`` (open, ``write_table``, ``close``: the data
and episodes files lerobot writes), ``av.open`` for writing (lerobot's video encoder) and ``h5py.File`` for writing
(the robomimic export). Each call is one **site** occurrence, labelled by the operation and the innermost frame of
surrol_data or lerobot that made it (``write surrol_data/datasets/journal.py:57``).

A counting run (``fail_at=None``) records the sites in call order; a failing run raises ``OSError(error)`` at the
``fail_at``-th call. A full disk (ENOSPC) then refuses every later call that needs space (open for writing, write,
flush, fsync, mkdir, link; rename, unlink and rmdir still work there), a read-only disk (EROFS) every later change,
and an I/O error (EIO) is the one call only: what the disk does.
"""

from __future__ import annotations

import builtins
import errno
import io
import os
import stat
import sys
from pathlib import Path

ERRORS = {"ENOSPC": errno.ENOSPC, "EIO": errno.EIO, "EROFS": errno.EROFS}
_NEEDS_SPACE = {"open", "write", "flush", "fsync", "mkdir", "link", "parquet-open", "parquet-write",
                "parquet-close", "video-open", "hdf5-open"}
_HERE = Path(__file__).resolve()
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND


def _caller() -> str:
    """``path:line`` of the innermost frame of surrol_data or lerobot (not this module) on the stack."""
    frame = sys._getframe(2)
    while frame is not None:
        name = frame.f_code.co_filename
        if name != str(_HERE):
            for package in ("surrol_data", "lerobot"):
                at = name.rfind(f"/{package}/")
                if at >= 0:
                    return f"{name[at + 1:]}:{frame.f_lineno}"
        frame = frame.f_back
    return "?"


class _File:
    """A file object whose ``write`` / ``flush`` (and ``writelines``) are calls of the injector."""

    def __init__(self, fh, injector: FaultInjector, name: str):
        self._fh, self._injector, self._name = fh, injector, name

    def write(self, data):
        self._injector.call("write", self._name)
        return self._fh.write(data)

    def writelines(self, lines):
        self._injector.call("write", self._name)
        return self._fh.writelines(lines)

    def flush(self):
        self._injector.call("flush", self._name)
        return self._fh.flush()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()

    def __iter__(self):
        return iter(self._fh)

    def __getattr__(self, name):
        return getattr(self._fh, name)


class FaultInjector:
    """``with FaultInjector(fail_at=k, error="ENOSPC") as faults: run()`` (see the module doc). ``sites``: the label
    of every call made so far, in order; ``failed``: the label of the call that was failed (None if none was)."""

    def __init__(self, fail_at: int | None = None, error: str = "ENOSPC"):
        self.fail_at = fail_at
        self.error = error
        self.code = ERRORS[error]
        self.sites: list[str] = []
        self.failed: str | None = None
        self._saved: list[tuple[object, str, object]] = []

    # ------------------------------------------------------------------ the one decision
    def call(self, op: str, filename=None) -> None:
        n = len(self.sites)
        self.sites.append(f"{op} {_caller()}")
        if self.fail_at is None:
            return
        if n == self.fail_at:
            self.failed = self.sites[-1]
            self._raise(filename)
        if self.failed is not None and n > self.fail_at:
            sticky = (self.code == errno.EROFS
                      or (self.code == errno.ENOSPC and op in _NEEDS_SPACE))
            if sticky:
                self._raise(filename)

    def _raise(self, filename) -> None:
        raise OSError(self.code, os.strerror(self.code), None if filename is None else str(filename))

    # ------------------------------------------------------------------ patching
    def _patch(self, owner, name: str, replacement) -> None:
        self._saved.append((owner, name, getattr(owner, name)))
        setattr(owner, name, replacement)

    def __enter__(self) -> FaultInjector:
        injector = self
        real_open, real_os = builtins.open, {n: getattr(os, n) for n in (
            "open", "write", "ftruncate", "sendfile", "fsync", "replace", "rename", "mkdir", "unlink", "remove",
            "rmdir", "link", "symlink")}

        def open_(file, mode="r", *args, **kwargs):
            # an open file descriptor (multiprocessing's pipes) is not a file on the disk
            writing = isinstance(mode, str) and any(c in mode for c in "wax+") and not isinstance(file, int)
            if writing:
                injector.call("open", file)
            fh = real_open(file, mode, *args, **kwargs)
            return _File(fh, injector, str(file)) if writing else fh

        self._patch(builtins, "open", open_)
        self._patch(io, "open", open_)

        def os_open(path, flags, *args, **kwargs):
            if flags & _WRITE_FLAGS:
                injector.call("open", path)
            return real_os["open"](path, flags, *args, **kwargs)

        self._patch(os, "open", os_open)

        real_fstat = os.fstat

        def wrap(op: str, name: str, on_fd: bool = False):
            real = real_os[name]

            def wrapped(*args, **kwargs):
                target = args[0] if args else None
                if on_fd:   # a pipe or a socket (multiprocessing's, the harness's own report) is no disk
                    try:
                        mode = real_fstat(target).st_mode
                        on_disk = stat.S_ISREG(mode) or stat.S_ISDIR(mode)
                    except (OSError, TypeError):
                        on_disk = False
                    if not on_disk:
                        return real(*args, **kwargs)
                injector.call(op, target)
                return real(*args, **kwargs)

            return wrapped

        for name in ("write", "ftruncate", "sendfile"):
            self._patch(os, name, wrap("write", name, on_fd=True))
        self._patch(os, "fsync", wrap("fsync", "fsync", on_fd=True))
        for op, names in (
                          ("rename", ("replace", "rename")), ("mkdir", ("mkdir",)),
                          ("unlink", ("unlink", "remove")), ("rmdir", ("rmdir",)), ("link", ("link", "symlink"))):
            for name in names:
                self._patch(os, name, wrap(op, name))
        self._patch_libraries()
        return self

    def _patch_libraries(self) -> None:
        injector = self
        import pyarrow.parquet as pq

        real_init, real_write, real_close = (pq.ParquetWriter.__init__, pq.ParquetWriter.write_table,
                                             pq.ParquetWriter.close)

        def init(self, where, *args, **kwargs):
            injector.call("parquet-open", where)
            return real_init(self, where, *args, **kwargs)

        def write_table(self, *args, **kwargs):
            injector.call("parquet-write")
            return real_write(self, *args, **kwargs)

        def close(self, *args, **kwargs):
            if getattr(self, "is_open", False):
                injector.call("parquet-close")
            return real_close(self, *args, **kwargs)

        self._patch(pq.ParquetWriter, "__init__", init)
        self._patch(pq.ParquetWriter, "write_table", write_table)
        self._patch(pq.ParquetWriter, "close", close)
        try:
            import av
        except ImportError:
            av = None
        if av is not None:
            real_av_open = av.open

            def av_open(file, mode="r", *args, **kwargs):
                if isinstance(mode, str) and "w" in mode:
                    injector.call("video-open", file)
                return real_av_open(file, mode, *args, **kwargs)

            self._patch(av, "open", av_open)
        h5py = sys.modules.get("h5py")
        if h5py is not None:
            real_file = h5py.File

            class File(real_file):
                def __init__(self, name, mode="r", *args, **kwargs):
                    if isinstance(mode, str) and mode != "r":
                        injector.call("hdf5-open", name)
                    super().__init__(name, mode, *args, **kwargs)

            self._patch(h5py, "File", File)

    def __exit__(self, *exc) -> None:
        while self._saved:
            owner, name, original = self._saved.pop()
            setattr(owner, name, original)


def distinct_sites(sites: list[str]) -> dict[str, int]:
    """Each site label -> the index of its first call (the call a trial fails to reach that site)."""
    first: dict[str, int] = {}
    for i, site in enumerate(sites):
        first.setdefault(site, i)
    return first

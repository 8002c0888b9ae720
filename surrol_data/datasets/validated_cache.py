"""Datasets the guard has already found valid, remembered by the digest of their bytes.

Every command checks its input before it trusts it (:func:`surrol_data.datasets.guard.require_valid`); at 10,000
episodes those checks read every frame and take minutes, for a dataset that has not changed since the last command.
So a dataset that passed is remembered by :func:`dataset_digest` — a SHA-256 over every file's relative path and
bytes (the writer's lock file aside), and over the checking code itself — and the next check of the same bytes with
the same code is skipped. Any changed byte (an edited provenance value, a swapped video, bit rot) changes the digest,
so it is checked again. Hashing is disk speed, far below the checks' cost.

The memory lives in the user's cache folder (``$XDG_CACHE_HOME/surrol_data/validated``, else
``~/.cache/surrol_data/validated``), never in the dataset: reading a dataset never writes to it. A cache that cannot
be written is simply not used. ``surrol-data validate`` always runs every check; it only adds to the memory.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from surrol_data.datasets.lock import LOCK_NAME

_CHUNK = 1 << 20


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "surrol_data" / "validated"


def _code_digest() -> bytes:
    """What the verdict depends on besides the dataset: the checking code (every module of this package, whatever
    validate imports from it) and the versions of the libraries that read the files."""
    from importlib.metadata import PackageNotFoundError, version

    h = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    for package in ("pyarrow", "numpy", "av"):
        try:
            h.update(f"{package}={version(package)}".encode())
        except PackageNotFoundError:
            h.update(package.encode())
    return h.digest()


def dataset_digest(root: str | Path) -> str:
    """SHA-256 (hex) of every file under ``root`` (relative path, size and bytes; the lock file left out) and of the
    checking code."""
    root = Path(root)
    h = hashlib.sha256(_code_digest())
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.name != LOCK_NAME):
        rel = path.relative_to(root).as_posix()
        h.update(f"\0{rel}\0{path.stat().st_size}\0".encode())
        with open(path, "rb") as fh:
            while chunk := fh.read(_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def known_valid(digest: str) -> bool:
    return (cache_dir() / digest).is_file()


def remember_valid(digest: str) -> None:
    """Remember ``digest`` as valid; silently nothing when the cache folder cannot be written."""
    try:
        folder = cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        (folder / digest).touch()
    except OSError:
        pass

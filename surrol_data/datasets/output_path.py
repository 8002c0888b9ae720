"""Where a command that makes a new dataset (or file) writes, for the ``--out`` it was given."""

from __future__ import annotations

import os
from pathlib import Path


def new_output(out: str | Path) -> Path:
    """The folder a command that makes a new dataset (or file) writes for ``--out out``: ``out`` itself, or, when it
    is a symbolic link to a path that does not exist yet, that path (the link then leads to what was written;
    written in the link's place, the output would have to replace the link)."""
    out = Path(out)
    if out.is_symlink() and not out.exists():
        return Path(os.path.realpath(out))
    return out

"""The shell command that opens a Rerun recording, as the user can paste it.

``rerun`` is a console script of the environment the toolkit runs in; it is on the user's PATH only when
that environment is active. Under ``uv run`` (which sets ``UV``) the user's own shell has no ``.venv/bin``
on PATH, so the command is ``uv run rerun FILE``; with the environment active (``rerun`` on PATH resolves to
the one beside this Python) it is plain ``rerun FILE``; otherwise the absolute path of that ``rerun``, or
``<this python> -m rerun FILE`` where there is no such script.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path


def rerun_open_command(recording: str | Path) -> str:
    """``uv run rerun FILE``, ``rerun FILE``, ``/abs/path/rerun FILE`` or ``python -m rerun FILE``: whichever
    works when pasted into the shell that started this process."""
    file = shlex.quote(str(recording))
    if os.environ.get("UV"):
        return f"uv run rerun {file}"
    here = shutil.which("rerun", path=str(Path(sys.executable).parent))
    if here is not None:
        on_path = shutil.which("rerun")
        if on_path is not None and Path(on_path).resolve() == Path(here).resolve():
            return f"rerun {file}"
        return f"{shlex.quote(here)} {file}"
    return f"{shlex.quote(sys.executable)} -m rerun {file}"

"""Commands to print for the user to paste: in the form that works in the shell that started this process.

A console script of the environment the toolkit runs in (``rerun``, ``surrol-data``) is on the user's PATH only
when that environment is active. Under ``uv run`` (which sets ``UV``) the user's own shell has no ``.venv/bin``
on PATH, so the command is ``uv run PROGRAM``; with the environment active (``PROGRAM`` on PATH resolves to
the one beside this Python) it is plain ``PROGRAM``; otherwise the absolute path of that script, or
``<this python> -m MODULE`` where there is no such script.

A Rerun recording opens in Rerun's native viewer, which needs a display; where there is none (an SSH session, a
container) the hint is ``surrol-data view FILE.rrd --web``, which serves it to a browser.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path


def as_run_here(program: str, module: str) -> str:
    """``uv run PROGRAM``, ``PROGRAM``, ``/abs/path/PROGRAM`` or ``python -m MODULE``: how the console script
    ``program`` of this environment runs when pasted into the shell that started this process."""
    if os.environ.get("UV"):
        return f"uv run {program}"
    here = shutil.which(program, path=str(Path(sys.executable).parent))
    if here is not None:
        on_path = shutil.which(program)
        if on_path is not None and Path(on_path).resolve() == Path(here).resolve():
            return program
        return shlex.quote(here)
    return f"{shlex.quote(sys.executable)} -m {module}"


def rerun_open_command(recording: str | Path) -> str:
    """The native viewer's command for ``recording``: ``uv run rerun FILE``, ``rerun FILE``, ``/abs/path/rerun
    FILE`` or ``python -m rerun FILE``."""
    return f"{as_run_here('rerun', 'rerun')} {shlex.quote(str(recording))}"


def web_view_command(recording: str | Path) -> str:
    """``surrol-data view FILE.rrd --web`` (in the form that runs here): the recording served to a browser."""
    return f"{as_run_here('surrol-data', 'surrol_data.cli')} view {shlex.quote(str(recording))} --web"


def recording_view_command(recording: str | Path) -> str:
    """What opens ``recording`` here: Rerun's native viewer where there is a display, else the web viewer."""
    from surrol_data.render.display import has_display

    if has_display():
        return rerun_open_command(recording)
    return web_view_command(recording)

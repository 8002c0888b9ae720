"""Run a shell command in a private mount namespace (``unshare --mount``): the tests mount a read-only bind or a
small tmpfs there, and the mounts vanish with the command, whatever happens to it."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def skip_reason() -> str:
    """Why mounts cannot be made here ("" when they can)."""
    if shutil.which("unshare") is None:
        return "unshare (util-linux) is not installed"
    probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "true"], capture_output=True)
    return "" if probe.returncode == 0 else "needs root to mount (unshare --mount)"


def run(shell: str, timeout: float) -> subprocess.CompletedProcess:
    """``sh -c shell`` in a private mount namespace, from the repository, with this checkout first on the path."""
    env = {**os.environ, "PYTHONPATH": f"{REPO_ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c", shell], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=timeout, env=env)

"""Start-up cost: `surrol-data --help` and the import of the CLI load none of the heavy packages.

A regression here is caught by what gets imported, not by a timing: `--help` must not pay for torch, lerobot,
pybullet, gymnasium (and numpy behind it), which each command imports only when it runs.
"""

import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "lerobot", "pybullet", "gymnasium", "numpy", "pandas", "pyarrow", "datasets", "rerun", "panda3d")


def _imported_modules(args: list[str]) -> set[str]:
    """Top-level modules imported by ``python -X importtime ARGS`` (its import log on stderr)."""
    result = subprocess.run([sys.executable, "-X", "importtime", *args], cwd=REPO_ROOT, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    modules = set()
    for line in result.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            modules.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    assert "surrol_data" in modules, "the import log was not read"
    return modules


def test_help_imports_no_heavy_package():
    imported = _imported_modules(["-m", "surrol_data.cli", "--help"])
    assert not imported & set(HEAVY), f"`surrol-data --help` imports {sorted(imported & set(HEAVY))}"


def test_a_command_help_imports_no_heavy_package():
    imported = _imported_modules(["-m", "surrol_data.cli", "collect", "--help"])
    assert not imported & set(HEAVY), f"`surrol-data collect --help` imports {sorted(imported & set(HEAVY))}"


def test_gymnasium_imported_later_still_leaves_the_environment_and_pygame_quiet():
    # The package no longer imports gymnasium itself: the first import of gymnasium, whoever makes it, must leave
    # PYGAME_HIDE_SUPPORT_PROMPT as it was, and gymnasium must still load whole (spaces, registry).
    code = ("import os, surrol_data, sys\n"
            "assert 'gymnasium' not in sys.modules\n"
            "import gymnasium.spaces, gymnasium as gym\n"
            "assert 'PYGAME_HIDE_SUPPORT_PROMPT' not in os.environ, 'gymnasium leaked its variable'\n"
            "assert gym.spaces.Box is gymnasium.spaces.Box and callable(gym.make)\n"
            "assert gym.__spec__.loader.get_filename('gymnasium').endswith('__init__.py')\n")
    env = {k: v for k, v in __import__("os").environ.items() if k != "PYGAME_HIDE_SUPPORT_PROMPT"}
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, timeout=300,
                            env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout == ""

"""Test-session environment: datasets are local, and the Hugging Face caches stay out of the user's home."""

import fcntl
import logging
import os
import sys
import tempfile
from pathlib import Path

import pytest

# Set before any test module imports lerobot / datasets (they read these at import); subprocess tests inherit them.
os.environ.setdefault("HF_DATASETS_CACHE", str(Path(tempfile.gettempdir()) / "surrol_data_test_hf_cache"))
os.environ.setdefault("HF_HUB_OFFLINE", "1")


def pytest_configure(config):
    config.addinivalue_line("markers", "browser: needs headless Chromium (apt-get install chromium); skips without it")


# The default run is spread over two worker processes (pytest-xdist: `-n 2 --dist loadfile` in pyproject's addopts;
# `-n 0` runs everything in this one). A test file is one unit of work, so that its module-scoped fixtures are built
# once. The files that take longest go first: one scheduled last would leave the other worker idle at the end. The
# SLURM tests start their own cluster and train in its jobs; test_study_runs makes the run's table1_quick study
# (below), which test_notebooks, queued behind the SLURM tests on the other worker, then finds made.
LONGEST_FIRST = ("test_slurm.py", "test_study_runs.py", "test_notebooks.py", "test_learning_from_interventions.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))   # stable: the rest keep their order


@pytest.fixture(scope="session")
def table1_quick_partial(tmp_path_factory) -> Path:
    """table1_quick (3 sources × 2 seeds, tiny), its first two runs (script/0, novice/0) trained by `surrol-data
    study table1_quick --next 2`: made once per test run (by the first worker to ask, under a lock, in the folder
    the workers' own temporary folders share), read (never written) by the study and notebook tests."""
    from typer.testing import CliRunner

    from surrol_data.cli import app

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base   # this run's, above popen-gwN
    out, made = shared / "study" / "table1_quick", shared / "study" / "made"
    out.parent.mkdir(exist_ok=True)
    with open(shared / "study.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)    # released when the file closes
        if not made.exists():
            result = CliRunner().invoke(app, ["study", "table1_quick", "--out", str(out), "--next", "2"])
            assert result.exit_code == 0, result.output
            made.touch()
    return out


_WINDOW_TASKS = ("hand", "leave", "scripted-trainee")   # the names the GUI tests give the window tasks that drive a session


@pytest.fixture(autouse=True)
def _no_window_task_outlives_its_test():
    """Panda3D's task manager is one per process: a driving task a test added (test_gui, test_interventions) would
    go on sending its keys to the next test's window, in any file, and end that session before it did what it was
    there for."""
    yield
    if "direct.task.TaskManagerGlobal" in sys.modules:
        from direct.task.TaskManagerGlobal import taskMgr

        for name in _WINDOW_TASKS:
            taskMgr.remove(name)


def _handlers() -> dict[str, list]:
    loggers = [logging.getLogger(), *(lg for lg in logging.Logger.manager.loggerDict.values()
                                      if isinstance(lg, logging.Logger))]
    return {lg.name: list(lg.handlers) for lg in loggers}


@pytest.fixture(autouse=True)
def _no_logging_handler_outlives_its_test():
    """A handler that code run in-process attached during a test (`logging.basicConfig` in a command's CLI, a library's
    own logging set-up) writes to that test's captured stream, which pytest closes afterwards: every later record of
    that logger, in any test, would then print a 'Logging error' traceback into that test's output."""
    before = _handlers()
    yield
    for name, handlers in _handlers().items():
        for handler in handlers:
            if handler not in before.get(name, ()) and not type(handler).__module__.startswith("_pytest"):
                logger = logging.getLogger(name) if name != "root" else logging.getLogger()
                logger.removeHandler(handler)

"""Test-session environment: datasets are local, and the Hugging Face caches stay out of the user's home."""

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


@pytest.fixture(scope="session")
def table1_quick_partial(tmp_path_factory) -> Path:
    """table1_quick (3 sources × 2 seeds, tiny), its first two runs (script/0, novice/0) trained by `surrol-data
    study table1_quick --next 2`: made once per session, read (never written) by the study and notebook tests."""
    from typer.testing import CliRunner

    from surrol_data.cli import app

    out = tmp_path_factory.mktemp("study") / "table1_quick"
    result = CliRunner().invoke(app, ["study", "table1_quick", "--out", str(out), "--next", "2"])
    assert result.exit_code == 0, result.output
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

"""Issue 28: `view` and `demo` print a command that opens the recording when pasted into the user's shell
(`rerun` is on PATH only inside the environment: `uv run rerun`, the absolute path, or `python -m rerun`)."""

import os
import shlex
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from surrol_data.viz.open_command import rerun_open_command


@pytest.fixture
def fake_env(tmp_path, monkeypatch):
    """A Python in tmp/bin with a `rerun` script beside it, outside uv run."""
    bin_dir = tmp_path / "env bin"
    bin_dir.mkdir()
    rerun = bin_dir / "rerun"
    rerun.write_text("#!/bin/sh\n")
    rerun.chmod(0o755)
    monkeypatch.delenv("UV", raising=False)
    monkeypatch.setattr(sys, "executable", str(bin_dir / "python"))
    return bin_dir


def test_under_uv_run_it_is_uv_run_rerun(monkeypatch):
    monkeypatch.setenv("UV", "/usr/bin/uv")
    assert rerun_open_command("eps.rrd") == "uv run rerun eps.rrd"
    assert rerun_open_command("my runs/eps.rrd") == "uv run rerun 'my runs/eps.rrd'"


def test_with_the_environment_active_it_is_plain_rerun(fake_env, monkeypatch):
    monkeypatch.setenv("PATH", f"{fake_env}{os.pathsep}/usr/bin")
    assert rerun_open_command("eps.rrd") == "rerun eps.rrd"


def test_outside_the_environment_it_is_the_absolute_path(fake_env, monkeypatch):
    monkeypatch.setenv("PATH", "/usr/bin")
    command = rerun_open_command("eps.rrd")
    assert shlex.split(command) == [str(fake_env / "rerun"), "eps.rrd"]


def test_without_a_rerun_script_it_is_python_dash_m(tmp_path, monkeypatch):
    monkeypatch.delenv("UV", raising=False)
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python3"))
    assert shlex.split(rerun_open_command("eps.rrd")) == [str(tmp_path / "python3"), "-m", "rerun", "eps.rrd"]


def test_this_environment_gives_a_command_that_exists(monkeypatch):
    """As a user runs `.venv/bin/surrol-data view ...` without activating the environment: never bare `rerun`."""
    monkeypatch.delenv("UV", raising=False)
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    program = shlex.split(rerun_open_command("eps.rrd"))[0]
    assert program != "rerun"
    assert Path(program).is_file() and os.access(program, os.X_OK)


def test_view_prints_the_pasteable_command(tmp_path, monkeypatch):
    from surrol_data.cli import app
    from surrol_data.collect.script_source import collect_script

    root = tmp_path / "reach"
    collect_script("NeedleReach", 1, root, max_steps=3, keep_failures=True, progress=False)
    monkeypatch.setenv("UV", "/usr/bin/uv")
    out = tmp_path / "eps.rrd"
    result = CliRunner().invoke(app, ["view", str(root), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert f"open it with: uv run rerun {out}" in result.output
    assert "open it with: rerun" not in result.output

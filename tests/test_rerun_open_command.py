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
    monkeypatch.setenv("DISPLAY", ":0")
    out = tmp_path / "eps.rrd"
    result = CliRunner().invoke(app, ["view", str(root), "--out", str(out), "--no-scene"])
    assert result.exit_code == 0, result.output
    assert f"open it with: uv run rerun {out}" in result.output
    assert "open it with: rerun" not in result.output
    # headless, the native viewer cannot open: the hint serves the recording to a browser
    monkeypatch.delenv("DISPLAY")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    result = CliRunner().invoke(app, ["view", str(root), "--out", str(out), "--no-scene"])
    assert f"open it with: uv run surrol-data view {out} --web" in result.output


def test_headless_the_hint_is_the_web_viewer_in_the_form_that_runs_here(fake_env, monkeypatch):
    from surrol_data.viz.open_command import recording_view_command

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("PATH", "/usr/bin")
    assert shlex.split(recording_view_command("a b.rrd")) == [sys.executable, "-m", "surrol_data.cli", "view",
                                                              "a b.rrd", "--web"]
    monkeypatch.setenv("UV", "/usr/bin/uv")
    assert recording_view_command("eps.rrd") == "uv run surrol-data view eps.rrd --web"
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert recording_view_command("eps.rrd") == "uv run rerun eps.rrd"


def test_the_demo_says_what_to_try_next_as_it_runs_here(monkeypatch, tmp_path):
    from surrol_data.demo import default_out, next_steps

    monkeypatch.setenv("UV", "/usr/bin/uv")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    lines = next_steps(Path("outputs/demo-1/dataset"), Path("outputs/demo-1/demo_vs_bc.rrd"))
    said = "\n".join(lines)
    assert "uv run surrol-data view outputs/demo-1/demo_vs_bc.rrd --web" in said
    assert "uv run surrol-data info outputs/demo-1/dataset" in said
    assert "uv run surrol-data train algo=ddpgbc task=NeedlePick demos=script seed=0" in said
    monkeypatch.chdir(tmp_path)
    first = default_out()
    assert first.parent == Path("outputs") and first.name.startswith("demo-")   # kept, not in /tmp
    first.mkdir(parents=True)
    assert default_out() != first


def test_view_serves_an_rrd_file_to_the_web_viewer(tmp_path):
    """`surrol-data view FILE.rrd --web` (the demo's headless hint) serves the recording's own data."""
    import re
    import subprocess
    import time
    from urllib.parse import unquote

    import numpy as np
    import rerun as rr

    from surrol_data.viz.ports import free_port

    made = tmp_path / "made.rrd"
    rec = rr.RecordingStream("surrol_data_test")
    rec.save(made)
    for i in range(3):
        rec.set_time("step", sequence=i)
        rec.log("world/marker_points", rr.Points3D(np.full((2, 3), float(i))))
    rec.flush()
    del rec
    env = {**os.environ, "RERUN_ANALYTICS": "off", "COLUMNS": "300"}
    proc = subprocess.Popen([sys.executable, "-m", "surrol_data.cli", "view", str(made), "--web",
                             "--no-open-browser"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        printed = []
        for line in proc.stdout:
            printed.append(line)
            if "http://" in line:
                break
        found = re.search(r"url=(rerun%2Bhttp[^ &]+proxy)", printed[-1])
        assert found, "".join(printed)
        copy = tmp_path / "copy.rrd"   # what a viewer connected to the server receives, saved by rerun itself
        rerun = Path(sys.executable).parent / "rerun"
        saver = subprocess.Popen([str(rerun), unquote(found[1]), "--port", str(free_port()), "--save", str(copy)],
                                 env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            printed_copy = ""
            for _ in range(60):
                if copy.is_file() and copy.stat().st_size > 0:
                    printed_copy = subprocess.run([str(rerun), "rrd", "print", str(copy)], env=env,
                                                  capture_output=True, text=True, timeout=60).stdout
                    if "marker_points" in printed_copy:
                        break
                time.sleep(0.5)
            assert "marker_points" in printed_copy
        finally:
            saver.terminate()
            saver.wait(timeout=30)
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_an_rrd_file_without_web_is_refused_with_the_way_to_serve_it(tmp_path):
    (tmp_path / "x.rrd").write_bytes(b"")
    from surrol_data.cli import app

    result = CliRunner().invoke(app, ["view", str(tmp_path / "x.rrd")])
    assert result.exit_code == 2 and "--web" in result.output

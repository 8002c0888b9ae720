"""How the training GUI keeps up while someone operates: latency after play, the longest wait between two frames,
frames/s while operating.

Usage: ``uv run python benchmarks/gui_speed.py [--size 1280x800] [--task NeedlePick] [--seconds 20]
[--display xvfb|offscreen]``

One run: the window opens (``xvfb``: an on-screen window in a virtual X display started here, the default when
``Xvfb`` is installed; ``offscreen``: Panda3D's offscreen buffer), chooses ``task``, the simulated expert
operates for ``seconds`` after play (paced at the task's control period, as in every GUI session), then exit.
Columns: *first frame* — play to the next frame the window draws; *first step* — play to the first drawn frame
of the session's own world (session start-up: env, recorder, device); *max gap* — the longest time between two
frames from play to exit; *median fps* — the median over the session's whole seconds of frames drawn in each;
*steps/s* — env steps drawn per second (the control period's pace: 5/s for the arms, 10/s for an ECM
task). The window's loop draws at most 30 frames/s. Panda3D draws with Mesa's llvmpipe where there is no GPU.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import tempfile
import time

from rich.console import Console
from rich.table import Table


def start_xvfb(size: tuple[int, int]) -> subprocess.Popen:
    """A virtual X display for the window; DISPLAY points at it."""
    for number in range(90, 120):
        if not os.path.exists(f"/tmp/.X11-unix/X{number}"):
            break
    proc = subprocess.Popen(["Xvfb", f":{number}", "-screen", "0", f"{size[0]}x{size[1]}x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while not os.path.exists(f"/tmp/.X11-unix/X{number}") and time.monotonic() < deadline:
        time.sleep(0.1)
    os.environ["DISPLAY"] = f":{number}"
    return proc


def measure(size: tuple[int, int], task: str, seconds: float, offscreen: bool) -> dict:
    from surrol_data.gui.app import TrainingApp

    app = TrainingApp(out=tempfile.mkdtemp(prefix="gui_speed_"), offscreen=offscreen, size=size)
    app.choose_task(task)
    app.set_session("operator", "expert", "gui-speed")
    for _ in range(5):   # the idle window, before play
        app.frame()
    marks: dict[str, float] = {}

    def watch(t):
        now = time.monotonic()
        if app.steps_drawn >= 1 and "first_step" not in marks:
            marks["first_step"] = now
        if now - marks["play"] > seconds:
            app.request_exit()
        return t.cont

    app.base.taskMgr.add(watch, "gui-speed-watch")
    marks["play"] = time.monotonic()
    app.play()
    app.run()
    frames = [t for t in app.frame_times if t > marks["play"]]
    gaps = [b - a for a, b in zip([marks["play"], *frames], frames)]
    start = marks.get("first_step", frames[0])
    per_second = [sum(1 for t in frames if s <= t < s + 1) for s in (start + k for k in range(int(frames[-1] - start)))]
    return {"first_frame_s": frames[0] - marks["play"], "first_step_s": marks.get("first_step", float("nan")) - marks["play"],
            "max_gap_s": max(gaps), "median_fps": statistics.median(per_second) if per_second else float("nan"),
            "steps_per_s": app.steps_drawn / max(frames[-1] - start, 1e-9), "frames": len(frames)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="1280x800", help="window size WxH")
    parser.add_argument("--task", default="NeedlePick")
    parser.add_argument("--seconds", type=float, default=20.0, help="how long the operator operates after play")
    parser.add_argument("--display", choices=("xvfb", "offscreen"),
                        default="xvfb" if shutil.which("Xvfb") else "offscreen")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    xvfb = start_xvfb(size) if args.display == "xvfb" else None
    try:
        r = measure(size, args.task, args.seconds, offscreen=xvfb is None)
    finally:
        if xvfb is not None:
            xvfb.terminate()
            xvfb.wait(timeout=10)
    table = Table(title=f"surrol-data gui, {args.task}, simulated expert, {size[0]}×{size[1]} ({args.display}), "
                        f"{os.cpu_count()} CPUs")
    for column in ("first frame (s)", "first step (s)", "max gap (s)", "median fps", "steps/s", "frames"):
        table.add_column(column, justify="right")
    table.add_row(f"{r['first_frame_s']:.3f}", f"{r['first_step_s']:.2f}", f"{r['max_gap_s']:.3f}",
                  f"{r['median_fps']:.1f}", f"{r['steps_per_s']:.2f}", str(r["frames"]))
    Console().print(table)


if __name__ == "__main__":
    main()

"""The web console's frame rate and input-to-frame latency for 1 and 2 browsers (headless Chromium), as a table.

First row (browsers 0): one session process alone, driven over its pipe as the server drives it, with a key held:
the views it streams per second with no browser on this machine (operators' browsers run on their own machines).
Then per configuration: a server (``surrol_data.web.serve``) on a free port, N pages in one headless Chromium (each its
own browser context: another person's browser), each with an operator who presses play and then taps the left/right
keys (held 0.4 s, released 0.4 s) for ``--seconds``. Measured in the pages:

* frames/s: the views drawn on the page's canvas per second of wall time;
* input-to-frame latency: from the page sending a key change to drawing the first view the session stepped with it
  (median, p95), as recorded in each episode's provenance;
* CPU ms/frame: the session process's CPU time (user + system, from /proc) per frame it streamed: the env step, the
  render, the JPEG; a loaded machine stretches wall time, not this. 1000 / it is the frames/s one free core gives.

``paced``: the session steps at the task's control period (0.2 s for the PSM tasks: 5 steps/s), as a person
operates; three views are streamed a step (the states at a third and two thirds of it and at its end, a third of a
step apart: 15 a second). ``unpaced``: the steps and their views run back to back (the console's capacity).

    uv run python benchmarks/web_console.py --seconds 20
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from headless_chromium import PACKAGE, Chromium, chromium  # noqa: E402

SERVER = ("import sys; from surrol_data.web import serve; "
          "serve(sys.argv[1], [sys.argv[2]], port=0, size=(int(sys.argv[3]), int(sys.argv[4])), "
          "realtime=sys.argv[5] == 'paced', renderer=sys.argv[6])")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    import os

    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(browsers: int, mode: str, seconds: float, size: tuple[int, int], task: str, renderer: str) -> dict:
    out = Path(tempfile.mkdtemp(prefix="surrol-web-bench-"))
    proc = subprocess.Popen([sys.executable, "-c", SERVER, str(out), task, str(size[0]), str(size[1]), mode, renderer],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    url = None
    for line in proc.stdout:
        lines.append(line)
        if (found := re.search(r"open (http://\S+)", line)):
            url = found.group(1)
            break
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    try:
        with Chromium() as browser:
            pages = [browser.new_page() for _ in range(browsers)]
            for i, page in enumerate(pages):
                page.goto(url)
                page.wait_for("document.getElementById('who')?.open")
                page.js(f"localStorage.setItem('surrol.operator', 'bench{i}'); "
                        "localStorage.setItem('surrol.skill', 'unknown'); location.reload()")
                page.wait_for("window.consoleStats && window.consoleStats.frames > 0 && "
                              "!document.getElementById('play').disabled", timeout=300)
            for page in pages:
                page.js("document.getElementById('play').click()")
            for page in pages:
                page.wait_for("window.consoleStats.hud && window.consoleStats.hud.playing", timeout=300)
            pids = [int(p) for p in re.findall(r"process (\d+)", "".join(lines))]
            cpu0 = sum(cpu_seconds(p) for p in pids)
            for page in pages:
                page.js("window.consoleStats.latencies = []; window.consoleStats.mark = performance.now(); "
                        "window.consoleStats.frames0 = window.consoleStats.frames")
            start = time.monotonic()
            key = 0
            while time.monotonic() - start < seconds:
                for page in pages:
                    page.key("ad"[key % 2], True)
                time.sleep(0.4)
                for page in pages:
                    page.key("ad"[key % 2], False)
                time.sleep(0.4)
                key += 1
            cpu = sum(cpu_seconds(p) for p in pids) - cpu0
            stats = [page.js("({frames: window.consoleStats.frames - window.consoleStats.frames0, "
                             "ms: performance.now() - window.consoleStats.mark, lat: window.consoleStats.latencies})")
                     for page in pages]
            for page in pages:
                page.tap("Escape")
    finally:
        proc.send_signal(2)
        try:
            proc.wait(120)
        except subprocess.TimeoutExpired:
            proc.kill()
    frames = sum(s["frames"] for s in stats)
    fps = [s["frames"] / (s["ms"] / 1000) for s in stats]
    lat = np.concatenate([np.asarray(s["lat"], float) for s in stats]) if stats else np.zeros(0)
    return {"browsers": browsers, "mode": mode, "fps": float(np.mean(fps)), "frames": frames,
            "lat_median": float(np.median(lat)) if lat.size else float("nan"),
            "lat_p95": float(np.percentile(lat, 95)) if lat.size else float("nan"), "latencies": int(lat.size),
            "cpu_ms_per_frame": 1000 * cpu / max(frames, 1)}


def run_without_page(seconds: float, size: tuple[int, int], task: str, renderer: str) -> dict:
    """One session process alone, driven over its pipe as the server drives it (a key held): the views it streams per
    second and the gaps between them, with no browser on this machine (where operators' browsers run elsewhere,
    this is what the server gives each of them)."""
    import multiprocessing

    from surrol_data.web.worker import worker_main

    ctx = multiprocessing.get_context("spawn")
    ours, theirs = ctx.Pipe()
    proc = ctx.Process(target=worker_main, args=(theirs, task, "bench", "unknown", 0, size, renderer, True), daemon=True)
    proc.start()
    try:
        while ours.recv()[0] != "task":
            pass
        ours.send(("play", "keyboard"))
        stamps: list[float] = []
        cpu0 = None
        while not stamps or stamps[-1] - stamps[0] < seconds:
            message = ours.recv()
            if message[0] == "frame" and message[1]["hud"]["playing"]:
                if cpu0 is None:
                    cpu0 = cpu_seconds(proc.pid)
                    ours.send(("input", {"seq": 1, "keys": ["a", "s"]}))
                stamps.append(time.monotonic())
        cpu = cpu_seconds(proc.pid) - cpu0
        ours.send(("quit",))
    finally:
        proc.join(30)
        if proc.is_alive():
            proc.kill()
    gaps = np.diff(stamps) * 1000
    return {"browsers": "0 (pipe)", "mode": "paced", "fps": (len(stamps) - 1) / (stamps[-1] - stamps[0]),
            "lat_median": float("nan"), "lat_p95": float("nan"), "latencies": 0,
            "cpu_ms_per_frame": 1000 * cpu / (len(stamps) - 1), "gaps": (np.median(gaps), np.percentile(gaps, 95))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measured time per configuration")
    parser.add_argument("--browsers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--modes", nargs="+", default=["paced", "unpaced"], choices=["paced", "unpaced"])
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--task", default="NeedlePick")
    parser.add_argument("--renderer", default="auto", choices=["auto", "panda3d", "tiny"])
    args = parser.parse_args()
    if chromium() is None:
        sys.exit(f"needs headless Chromium: apt-get install {PACKAGE}")
    from surrol_data.web import pick_renderer

    size = tuple(int(v) for v in args.size.split("x"))
    renderer = pick_renderer(args.renderer)
    rows = [run_without_page(args.seconds, size, args.task, renderer)]
    rows += [run(n, mode, args.seconds, size, args.task, renderer) for mode in args.modes for n in args.browsers]
    print(f"\nweb console, {args.task}, {renderer} view {size[0]}x{size[1]}, {args.seconds:.0f} s per row "
          f"(wall-clock figures depend on the machine's load; CPU ms/frame much less). Browsers 0: the session "
          f"process alone, read from its pipe (gaps between views: median {rows[0]['gaps'][0]:.0f} ms, p95 "
          f"{rows[0]['gaps'][1]:.0f} ms); the others: pages in a headless Chromium on this machine\n")
    print("| browsers | stepping | frames/s per browser | latency median (ms) | latency p95 (ms) | latencies | "
          "CPU ms/frame |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for r in rows:
        latency = [f"{v:.0f}" if np.isfinite(v) else "—" for v in (r["lat_median"], r["lat_p95"])]
        print(f"| {r['browsers']} | {r['mode']} | {r['fps']:.1f} | {latency[0]} | {latency[1]} | "
              f"{r['latencies']} | {r['cpu_ms_per_frame']:.0f} |")


if __name__ == "__main__":
    main()

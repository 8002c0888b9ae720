"""How long `surrol-data demo` takes end to end, as a new user runs it, and where the time goes.

    python benchmarks/demo_speed.py                 # one `surrol-data demo` (defaults: 20 demos, 20 eval episodes)
    python benchmarks/demo_speed.py --runs 3        # the median of three runs
    python benchmarks/demo_speed.py --runs 1 -- --num-episodes 5 --eval-episodes 5   # extra demo options after --

Each run is a fresh process (`python -m surrol_data.cli demo --out <temp folder>`), so imports are included as a
user pays them. Its stdout is read line by line as it is printed: the time at which each of the demo's four
stage titles (``1/4 collect ...`` to ``4/4 report ...``) appears splits the wall time into start-up (imports, up
to the first title), collect, train BC, evaluate (oracle and BC rollouts) and report. The table has one row per
run and, with several runs, the median of each column.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

REPO = Path(__file__).resolve().parents[1]
STAGES = ("start-up", "collect", "train BC", "evaluate", "report")
TITLE = re.compile(r"\b([1-4])/4 ")


def time_demo(extra: list[str]) -> dict[str, float]:
    """One `surrol-data demo` in a new process: seconds per stage and in total."""
    with tempfile.TemporaryDirectory(prefix="demo_speed_") as tmp:
        cmd = [sys.executable, "-m", "surrol_data.cli", "demo", "--out", str(Path(tmp) / "demo"), *extra]
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "120"}
        t0 = time.perf_counter()
        marks = [t0]   # when each stage began
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        tail = []
        for line in proc.stdout:
            tail = (tail + [line])[-20:]
            match = TITLE.search(line)
            if match and int(match.group(1)) == len(marks):
                marks.append(time.perf_counter())
        end = time.perf_counter()
        if proc.wait() != 0 or len(marks) != len(STAGES):
            sys.exit(f"`{' '.join(cmd)}` failed (exit {proc.returncode}):\n{''.join(tail)}")
    times = {name: b - a for name, a, b in zip(STAGES, marks, [*marks[1:], end])}
    times["total"] = end - t0
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=1,
                        help="how many times to run the demo (the table adds the median)")
    args, extra = parser.parse_known_args()
    extra = [a for a in extra if a != "--"]
    console = Console()
    results = []
    for i in range(args.runs):
        console.print(f"run {i + 1}/{args.runs}: surrol-data demo {' '.join(extra)}".rstrip())
        results.append(time_demo(extra))
    table = Table(title=f"surrol-data demo, wall seconds ({os.cpu_count()} CPUs)")
    for col in ("run", *STAGES, "total"):
        table.add_column(col, justify="right")
    for i, r in enumerate(results, 1):
        table.add_row(str(i), *(f"{r[k]:.1f}" for k in (*STAGES, "total")))
    if len(results) > 1:
        table.add_row("median", *(f"{statistics.median(r[k] for r in results):.1f}" for k in (*STAGES, "total")))
    console.print(table)


if __name__ == "__main__":
    main()

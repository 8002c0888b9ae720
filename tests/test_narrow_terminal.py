"""Issue 28: the command line's tables are readable in an 80-column terminal: headers whole, never "Ope… Suc…"."""

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console

from surrol_data.evaluation.assess import ASSESS_COLUMNS
from surrol_data.evaluation.terminal_table import terminal_table

REPO = Path(__file__).resolve().parents[1]
ROWS = [{"group": "alice (haptic)", "skill": "expert", "episodes": 10, "success_rate": 0.9, "steps_to_success": 41.5,
         "path_length_cm": 12.25, "sparc": -1.8, "log_dimensionless_jerk": -6.1, "idle_time_s": 0.4,
         "clutch_uses": 1.0, "jaw_closures": 1.2, "errors": 0.1, "meets_benchmark": 0.5, "proficient_at": "3"},
        {"group": "all [expert]", "skill": "expert", "episodes": 10, "success_rate": 0.9,
         "steps_to_success": float("nan")}]


def _render(width: int) -> list[str]:
    console = Console(file=io.StringIO(), width=width, color_system=None)
    console.print(terminal_table(console, ROWS, ASSESS_COLUMNS))
    return console.file.getvalue().splitlines()


def _whole(lines: list[str], text: str) -> bool:
    return any(text in line for line in lines)


@pytest.mark.parametrize("width", [60, 80, 100])
def test_a_table_too_wide_for_the_terminal_is_turned_on_its_side(width):
    lines = _render(width)
    assert all(len(line) <= width for line in lines)
    assert "…" not in "\n".join(lines)
    for column in ASSESS_COLUMNS:
        assert _whole(lines, column.header), (column.header, lines)
    assert _whole(lines, "all [expert]") and _whole(lines, "41.5") and _whole(lines, "—")


def test_a_table_that_fits_keeps_one_row_per_line():
    lines = _render(220)
    header = next(line for line in lines if "Operator / group" in line)
    assert all(column.header in header for column in ASSESS_COLUMNS)
    assert any(line.lstrip().startswith("alice (haptic)") for line in lines)


def test_assess_at_80_columns_shows_whole_headers(tmp_path):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path / "reach"
    collect_script("NeedleReach", 2, root, max_steps=20, keep_failures=True, progress=False)
    done = subprocess.run([sys.executable, "-m", "surrol_data.cli", "assess", str(root)], capture_output=True,
                          text=True, timeout=300, env={**os.environ, "COLUMNS": "80", "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.splitlines()
    assert "…" not in done.stdout and all(len(line) <= 80 for line in lines)
    for column in ASSESS_COLUMNS:
        assert _whole(lines, column.header), (column.header, done.stdout)


def test_the_proficiency_summary_of_demo_and_eval_fits_80_columns():
    from surrol_data.demo import print_summary

    console = Console(file=io.StringIO(), width=80, color_system=None)
    summary = {"episodes": 20, "success_rate": 0.95, "final_success_rate": 0.9, "mean_steps_to_success": 61.2,
               "mean_path_length_cm": 14.3}
    print_summary(console, {"script demos (dataset)": summary, "oracle rollouts": summary, "BC policy": summary})
    text = console.file.getvalue()
    assert "…" not in text and all(len(line) <= 80 for line in text.splitlines())
    words = set(text.replace("┃", " ").replace("│", " ").split())   # a long header wraps between its words
    assert {"source", "episodes", "success", "final", "steps", "to", "complete", "path", "length", "cm"} <= words

"""Markdown report: table numbers match the metrics, the PNG is a real image, links are there."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from surrol_data.datasets.metrics import summarize, trajectory_proficiency
from surrol_data.datasets.trajectory import Trajectory
from surrol_data.evaluation.report import (Column, SUMMARY_COLUMNS, metrics_table_markdown, plot_comparison,
                                           summary_rows, write_report)

TABLE_Z = 0.675


def straight_reach(steps: int, length_m: float, succeed_at: int | None) -> Trajectory:
    """Tip moves along x by ``length_m`` in equal steps; success from step ``succeed_at`` (1-based) on."""
    tip = np.zeros((steps + 1, 1, 3), np.float32)
    tip[:, 0, 0] = np.linspace(0.0, length_m, steps + 1)
    tip[:, 0, 2] = TABLE_Z + 0.03
    success = np.zeros(steps, bool)
    if succeed_at is not None:
        success[succeed_at - 1:] = True
    action = np.zeros((steps, 5), np.float32)
    action[:, 0] = length_m / steps / 0.01
    action[:, 4] = np.where(np.arange(steps) >= steps // 2, -1.0, 1.0)   # one jaw closure
    obs = np.zeros((steps + 1, 19), np.float32)
    return Trajectory(observation=obs, achieved_goal=obs[:, :3], desired_goal=obs[:, :3], action=action,
                      reward=success.astype(np.float32) - 1, success=success,
                      terminated=np.zeros(steps, bool), tip_position=tip,
                      jaw_angle=np.full((steps + 1, 1), 0.5, np.float32))


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG file"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


@pytest.fixture
def demos():
    # 10 steps over 10 cm → 1 cm per step; path to success = steps_to_success cm.
    return {
        "oracle": [straight_reach(10, 0.10, 6), straight_reach(10, 0.10, 8)],
        "haptic": [straight_reach(10, 0.10, 10), straight_reach(10, 0.10, None)],
    }


def test_table_rows_match_metrics(demos):
    rows = summary_rows(demos, {"BC policy": {"episodes": 20, "success_rate": 0.45, "final_success_rate": 0.4,
                                              "mean_steps_to_success": 31.25, "mean_path_length_cm": 7.5,
                                              "mean_log_dimensionless_jerk": float("nan"),
                                              "mean_jaw_closures": 1.2}})
    table = metrics_table_markdown(rows)
    lines = table.strip().splitlines()
    assert lines[0].startswith("| Source | Episodes | Success rate")
    assert lines[2].startswith("| oracle | 2 | 100 % | 100 % | 7.0 | 7.00 |")
    assert lines[3].startswith("| haptic | 2 | 50 % | 50 % | 10.0 | 10.00 |")
    assert lines[4] == "| BC policy | 20 | 45 % | 40 % | 31.2 | 7.50 | — | 1.2 |"


def test_custom_columns_and_missing_values():
    cols = (Column("source", "Source"), Column("skill", "Skill"), Column("success_rate", "Success", str))
    table = metrics_table_markdown([{"source": "haptic", "skill": "expert", "success_rate": 1.0},
                                    {"source": "a|b", "success_rate": math.nan}], cols)
    assert "| haptic | expert | 1.0 |" in table
    assert "| a\\|b | — | — |" in table
    with pytest.raises(ValueError):
        metrics_table_markdown([], ())


def test_write_report(tmp_path, demos):
    evaluations = {"oracle rollouts": summarize([trajectory_proficiency(t) for t in demos["oracle"]]),
                   "BC policy": summarize([trajectory_proficiency(straight_reach(12, 0.15, 12))])}
    rrd = tmp_path / "recordings" / "episodes.rrd"
    rrd.parent.mkdir()
    rrd.write_bytes(b"")
    loss = {"train": list(np.geomspace(1.0, 0.01, 20)), "validation": list(np.geomspace(1.2, 0.05, 20))}
    report = write_report(tmp_path / "report", "NeedlePick: demos and BC", demos=demos, evaluations=evaluations,
                          training_loss=loss, rrd_path=rrd, sections=[("Notes", "Synthetic data.")])
    text = report.read_text()
    assert report.name == "report.md"
    assert text.startswith("# NeedlePick: demos and BC")
    for header in (c.header for c in SUMMARY_COLUMNS):
        assert header in text
    assert "| BC policy | 1 | 100 % | 100 % | 12.0 | 15.00 |" in text
    assert "![comparison of sources](comparison.png)" in text
    assert "](../recordings/episodes.rrd)" in text
    assert "## Notes" in text and "BC loss over 20 epochs" in text
    width, height = _png_size(report.parent / "comparison.png")
    assert 800 <= width <= 3000 and 300 <= height <= 1500


def test_plot_without_loss_or_episodes(tmp_path):
    rows = [{"source": "oracle", "mean_steps_to_success": 20.0, "mean_path_length_cm": 9.0},
            {"source": "never", "mean_steps_to_success": float("nan"), "mean_path_length_cm": float("nan")}]
    png = plot_comparison(tmp_path / "p.png", rows, training_loss=[0.5, 0.3, 0.2])
    assert _png_size(png)[0] > 800
    png2 = plot_comparison(tmp_path / "q.png", rows)
    assert _png_size(png2)[0] < _png_size(png)[0]   # two panels instead of three
    with pytest.raises(ValueError, match="no rows"):
        plot_comparison(tmp_path / "r.png", [])


def test_write_report_needs_content(tmp_path, demos):
    with pytest.raises(ValueError, match="nothing to report"):
        write_report(tmp_path, "empty")
    with pytest.raises(ValueError, match="both a demo source and an evaluation"):
        summary_rows(demos, {"oracle": {}})

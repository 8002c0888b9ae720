"""demos.md shows each demo source's per-demo distributions (steps, path, failed attempts, retries), not only means."""

from __future__ import annotations

import math

import pandas as pd

from surrol_data.study.demo_sets import _per_demo, demo_distributions_markdown


def test_per_demo_distributions_take_steps_and_path_over_successes_and_counts_over_all():
    ep = pd.DataFrame({"success": [True, True, True, False],
                       "steps_to_success": [100.0, 110.0, 120.0, math.nan],
                       "path_length_cm": [12.0, 13.0, 14.0, 20.0],
                       "failed_attempts": [0, 1, 0, 3], "retries": [0, 1, 0, 2]})
    per = _per_demo(ep)
    assert per["steps_to_success"] == [100.0, 110.0, 120.0]
    assert per["path_length_cm"] == [12.0, 13.0, 14.0]          # the failed demo's 20 cm is not a demo's path
    assert per["failed_attempts"] == [0.0, 1.0, 0.0, 3.0]
    table = demo_distributions_markdown([{"source": "novice", "per_demo": per}])
    row = table.splitlines()[-1]
    assert row.startswith("| novice | 110 [105–115], 100–120 | 13.0 [12.5–13.5], 12.0–14.0 |"), row
    # failed attempts 0 / 1 / 2 / 3+: two of four demos none, one one, none two, one three
    assert "| 50 / 25 / 0 / 25 | 50 / 25 / 25 / 0 |" in row, row


def test_a_source_without_attempt_records_shows_dashes():
    table = demo_distributions_markdown([{"source": "script", "per_demo": {"steps_to_success": [109.0]}}])
    assert table.splitlines()[-1] == "| script | 109 [109–109], 109–109 | — | — | — | — | — |"

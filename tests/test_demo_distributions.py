"""demos.md shows each demo source's per-demo distributions (steps, path, failed attempts, retries), not only means, and
what each set is matched to."""

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


def test_a_task_without_the_papers_demo_figures_matches_its_sources_to_one_another(monkeypatch, tmp_path):
    """NeedlePick's sources are judged against the paper's demo sets; another task's against the sources' mean."""
    from types import SimpleNamespace

    import surrol_data.evaluation.assess as assess
    from surrol_data.study.demo_sets import demo_quality, demo_quality_markdown

    per_source = {"scripted": (120.0, 12.0), "novice": (125.0, 12.0), "expert": (130.0, 12.0)}
    rest = dict.fromkeys(("sparc", "log_dimensionless_jerk", "idle_time_s", "failed_grasps", "jaw_closures",
                          "clutch_uses"), 0.0)
    episodes = pd.DataFrame([{"skill": skill, "success": True, "steps_to_success": steps, "path_length_cm": path, **rest}
                             for skill, (steps, path) in per_source.items()])
    monkeypatch.setattr(assess, "assess_dataset", lambda path: SimpleNamespace(episodes=episodes))
    sets = {source: tmp_path / "set" for source in ("script", "novice", "expert")}

    # NeedlePick: against the paper's 109 / 117 / 113 steps, the script's 120 (+10.1 %) and the expert's 130 (+15 %) miss
    paper = demo_quality(sets)
    assert [(r["paper_steps"], r["matched"]) for r in paper] == [(109.0, "no"), (117.0, "yes"), (113.0, "no")]
    assert "Paper steps" in demo_quality_markdown(paper, True) and "near the needle" in demo_quality_markdown(paper, True)
    # Another task: against the sources' mean (125 steps, 12 cm), all three are within ±10 %
    other = demo_quality(sets, "PegTransfer")
    assert [(r["paper_steps"], r["paper_path"], r["matched"]) for r in other] == [(125.0, 12.0, "yes")] * 3
    text = demo_quality_markdown(other, True, "PegTransfer")
    assert "matched to one another" in text and "Sources' mean steps" in text and "near the block" in text

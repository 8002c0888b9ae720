"""The report's Table I at the report epochs, its attempts-and-recovery and probe tables, built from synthetic run
folders whose per-episode files say exactly what the tables must show (fast: no training)."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from surrol_data.evaluation.study_report import discover_runs, table1_estimates, write_study_report

HORIZON = 150


def _run(root, source, seed, *, report=None, per_epoch=None):
    folder = root / source / f"seed{seed}"
    folder.mkdir(parents=True)
    rows = [{"epoch": e, "success_rate": 0.5, "steps_to_complete": 40.0, "economy_of_motion_cm": 12.0}
            for e in (0, 50, 100)]
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (folder / "config.json").write_text(json.dumps({
        "env_id": "SurRoL/NeedlePick-v0", "seed": seed, "demos": {"name": source},
        "schedule": {"max_episode_steps": HORIZON, "eval_episodes": 20}}))
    if report is not None:
        pd.DataFrame(report).to_csv(folder / "report_episodes.csv", index=False)
    if per_epoch is not None:
        pd.DataFrame(per_epoch).to_csv(folder / "eval_episodes.csv", index=False)
    return folder


def _episode(epoch, kind, outcome, steps=-1, path=10.0, probed=None, retries=0):
    success = steps > 0
    attempts = {"no_attempt": 0, "first_held": 1, "stall": 1, "retried_recovered": 2, "retried_not_recovered": 2}
    row = {"epoch": epoch, "kind": kind, "final_success": success, "success": success, "steps_to_success": steps,
           "path_length_cm": path, "attempts": attempts[outcome], "failed_attempts": int(outcome != "first_held"),
           "retries": int(outcome.startswith("retried")), "attempt_outcome": outcome}
    if kind == "probe":
        row["probed"], row["probe_retries"] = probed, retries
    return row


def _script_report(epoch):
    return [_episode(epoch, "eval", "first_held", 20, 10.0), _episode(epoch, "eval", "retried_recovered", 40, 14.0),
            _episode(epoch, "eval", "stall"), _episode(epoch, "eval", "stall"),
            _episode(epoch, "probe", "stall", probed=True),
            _episode(epoch, "probe", "first_held", 60, probed=True, retries=1),   # retried off the mid-arc point
            _episode(epoch, "probe", "first_held", 30, probed=False)]   # the probe never fired: not counted


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    _run(root, "script", 0, report=_script_report(50) + _script_report(100))
    _run(root, "script", 1, report=_script_report(50) + _script_report(100))
    # a run from before the attempt measure: the old flicker columns, no report file
    _run(root, "novice", 0, per_epoch=[{"epoch": 100, "final_success": True, "success": True, "steps_to_success": 30,
                                        "first_grasp_failed": True, "recovered": True},
                                       {"epoch": 100, "final_success": False, "success": False, "steps_to_success": -1,
                                        "first_grasp_failed": True, "recovered": False}])
    return root


def test_table1_at_the_report_epochs_stands_on_the_report_episodes(runs):
    est = table1_estimates(discover_runs([runs]), [100])[100]
    assert est["success_rate"]["script"].mean == pytest.approx(0.5)            # 2 of 4 fresh episodes
    assert est["steps_to_complete"]["script"].mean == pytest.approx(30.0)       # (20 + 40) / 2
    assert est["steps_to_complete_horizon"]["script"].mean == pytest.approx((20 + 40 + 2 * HORIZON) / 4)
    assert est["economy_of_motion_cm"]["script"].mean == pytest.approx(12.0)
    # the old run: the logged row, and the horizon convention from its per-epoch episodes
    assert est["success_rate"]["novice"].mean == pytest.approx(0.5)
    assert est["steps_to_complete"]["novice"].mean == pytest.approx(40.0)
    assert est["steps_to_complete_horizon"]["novice"].mean == pytest.approx((30 + HORIZON) / 2)


def test_the_report_tables_and_what_they_lack(runs, tmp_path):
    md = write_study_report([runs], tmp_path)["markdown"].read_text()   # epochs 50 and 100, the paper's
    assert "| Steps to complete (successes only) | 100 |" in md
    assert "| Steps to complete (failures at the horizon) | 100 | 90.0 ± 0.0 [90.0, 90.0] | 24.0 ± 10.4 |" in md
    assert "Table I stands on epoch 50: 2 run(s) on their kept actor's evaluation of 4 fresh episodes" in md
    assert "the per-epoch evaluation (20 episodes) of novice/0 (no report_episodes.csv)" in md
    # the paper's ± in every one of its cells
    assert "| 101.8 ± 27.1 |" in md and "| 86.7 ± 2.4 |" in md and "| 13.5 ± 1.6 |" in md
    attempts = md.split("## Attempts and recovery", 1)[1].split("##", 1)[0]
    script_row = next(line for line in attempts.splitlines() if line.startswith("| script | 100 |"))
    cells = [c.strip() for c in script_row.strip("|").split("|")]
    # episodes pooled over 2 seeds: 8; attempts 1+2+1+1 per seed; first attempt failed in 6, retried in 2
    assert cells[2:4] == ["2", "8 (report)"] and cells[4].startswith("1.25")
    assert cells[5].startswith("25 %") and cells[5].endswith("(n=8)")
    assert cells[6].startswith("33 %") and cells[6].endswith("(n=6)")
    assert cells[7].startswith("33 %") and cells[8].startswith("67 %") and cells[9].startswith("0 %")
    probe = md.split("## Induced failure", 1)[1].split("##", 1)[0]
    script_probe = next(line for line in probe.splitlines() if line.startswith("| script | 100 |"))
    cells = [c.strip() for c in script_probe.strip("|").split("|")]
    assert cells[3:5] == ["6", "4"] and cells[5].startswith("50 %") and cells[6].startswith("50 %")
    assert cells[7].startswith("50 %") and cells[7].endswith("(n=4)")
    # the old run is named, with why, in both sections
    assert attempts.count("Not in the table: novice/0 (epoch 50, 100)") == 1
    assert "no per-episode attempt record" in attempts
    assert "Not in the table: novice/0 (epoch 50, 100): no probe episodes" in probe


def test_a_resumed_study_skips_a_finished_report_evaluation(tmp_path):
    from surrol_data.study.report_eval import has_report_episodes

    assert not has_report_episodes(tmp_path, [50, 100], 4)
    rows = [_episode(e, kind, "stall", probed=True) for e in (50, 100) for kind in ("eval", "probe") for _ in range(4)]
    pd.DataFrame(rows[:-1]).to_csv(tmp_path / "report_episodes.csv", index=False)
    assert not has_report_episodes(tmp_path, [50, 100], 4)     # killed before its last probe episode was written
    pd.DataFrame(rows).to_csv(tmp_path / "report_episodes.csv", index=False)
    assert has_report_episodes(tmp_path, [50, 100], 4) and not has_report_episodes(tmp_path, [50, 100], 100)

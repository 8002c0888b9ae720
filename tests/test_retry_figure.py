"""The retry figure (surrol_data/study/retry_figure.py): frames chosen by the recorded outcome of the probed episodes
(what followed the disabled close: the induced-failure table's measure), replayed with the run's kept actor and
checked against the record, drawn with a real renderer."""

from __future__ import annotations

import re
import shutil
from functools import partial
from pathlib import Path

import pandas as pd
import pytest
from PIL import Image

from surrol_data.evaluation.recovery_report import REPORT_FILE
from surrol_data.evaluation.study_report import Run, discover_runs, write_study_report
from surrol_data.study.retry_figure import (FIGURE_FILE, choose_episodes, retry_frames_section,
                                           write_retry_figure)


OUTCOME = {"stalled": (0, False), "retried_failed": (2, False), "retried_succeeded": (1, True)}   # retries, success


def _run(tmp_path: Path, source: str, seed: int, outcomes: list[str], probed: list[bool] | None = None) -> Run:
    path = tmp_path / source / f"seed{seed}"
    path.mkdir(parents=True)
    n = len(outcomes)
    pd.DataFrame({"epoch": [50] * n, "kind": ["probe"] * n, "episode": range(n), "seed": [2_100_000_000 + k for k in range(n)],
                  "probed": probed or [True] * n, "probe_from": [7] * n,
                  "probe_retries": [OUTCOME[o][0] for o in outcomes], "final_success": [OUTCOME[o][1] for o in outcomes],
                  }).to_csv(path / REPORT_FILE, index=False)
    return Run(path=path, task="NeedlePick", algo="ddpgbc", source=source, seed=seed, rows=[], config={})


def test_each_source_shows_the_first_episode_with_its_most_common_outcome(tmp_path):
    runs = [_run(tmp_path, "script", 1, ["stalled", "stalled", "retried_succeeded"]),
            _run(tmp_path, "script", 0, ["retried_succeeded", "stalled", "stalled"], probed=[True, False, True]),
            _run(tmp_path, "novice", 0, ["retried_failed", "retried_failed"]),
            _run(tmp_path, "novice", 1, ["retried_succeeded", "retried_succeeded", "retried_succeeded"])]
    chosen = {c.source: c for c in choose_episodes(runs, 50)}
    # script: stalled 3 of 5 probed (seed 0's second episode was not probed); shown from the lowest seed's run
    assert (chosen["script"].outcome, chosen["script"].share, chosen["script"].run.name, chosen["script"].seed) == \
        ("stalled", "3 of 5", "seed0", 2_100_000_002)
    # novice: the modal outcome is only in seed 1's run, so that run shows it
    assert (chosen["novice"].outcome, chosen["novice"].run.name, chosen["novice"].seed) == \
        ("retried_succeeded", "seed1", 2_100_000_000)
    assert choose_episodes(runs, 25) == []


def _probed_copy(study: Path, tmp_path: Path) -> Path:
    """The shared quick study's runs, their probe rows marked as probed: a 2-epoch policy never attempts a grasp, so
    the probe never took effect; the figure's pipeline is the same."""
    runs = tmp_path / "runs"
    shutil.copytree(study / "runs", runs)
    for path in runs.rglob(REPORT_FILE):
        rows = pd.read_csv(path)
        rows.loc[rows["kind"] == "probe", "probed"] = True
        rows.to_csv(path, index=False)
    return runs


def test_the_report_replays_each_chosen_episode_and_shows_its_frames(table1_quick_partial, tmp_path):
    runs = _probed_copy(table1_quick_partial, tmp_path)
    out = tmp_path / "report"
    write_study_report([runs], out, epochs=[1, 2], figures=partial(retry_frames_section, epoch=2))
    width, height = Image.open(out / FIGURE_FILE).size
    assert width > 1000 and height > 400          # a row of frames per source (script, novice)
    report = (out / "report.md").read_text()
    section = report[report.index("## After a failed first grasp: frames (epoch 2)"):]
    lines = [line for line in section.splitlines() if line.startswith("* ")]
    assert [line[2:].split("-trained")[0] for line in lines] == ["script", "novice"]
    assert all("`stalled` (2 of 2 probed episodes" in line for line in lines), lines
    assert f"![frames after a failed first grasp]({FIGURE_FILE})" in section
    assert "data:image/png;base64," in (out / "report.html").read_text()


def test_a_replay_that_does_not_match_the_record_is_refused(table1_quick_partial, tmp_path):
    runs_dir = _probed_copy(table1_quick_partial, tmp_path)
    for path in runs_dir.rglob(REPORT_FILE):
        rows = pd.read_csv(path)
        rows.loc[rows["kind"] == "probe", "probe_retries"] = 2   # not what the actor does
        rows.to_csv(path, index=False)
    runs = [r for r in discover_runs([runs_dir]) if r.source == "script"]
    with pytest.raises(RuntimeError, match=r"replayed as stalled \(disabled from action -1\), recorded as retried_failed"):
        write_retry_figure(runs, tmp_path, epoch=2)


def test_the_retry_tables_cover_epochs_25_50_100_beside_table_1s_epochs(table1_quick_partial, tmp_path):
    """After training, a study run is evaluated at Table I's epochs and at 25, 50 and 100 (those it reached), and the
    attempts and induced-failure tables show each; Table I keeps its own epochs."""
    from surrol_data.study.report_eval import evaluated_epochs

    assert evaluated_epochs((50, 100), 100) == (25, 50, 100)
    assert evaluated_epochs((1, 2), 2) == (1, 2)
    out = tmp_path / "report"
    write_study_report([table1_quick_partial / "runs"], out, epochs=[2], recovery_epochs=[1, 2, 25])
    report = (out / "report.md").read_text()
    table1 = report[report.index("## Table I"):report.index("## Learning curves")]
    probe = report[report.index("## Induced failure"):]
    probe = probe[:probe.index("\n## ", 1)]
    epochs_of = lambda text: {int(m) for m in re.findall(r"^\| \w+ \| (\d+) \|", text, re.M)}  # noqa: E731
    assert epochs_of(probe) == {1, 2}           # 25 is beyond these 2-epoch runs
    assert "| 1 |" not in table1 and "| 2 |" in table1


def test_the_frames_show_the_disabled_close_the_reopened_jaw_the_retry_and_the_success():
    from types import SimpleNamespace

    import numpy as np

    from surrol_data.study.retry_figure import _frame_steps

    jaw = np.ones(60)
    jaw[9:11] = -1      # the disabled close (actions 9–10), the jaw open again at action 11
    jaw[14:40] = -1     # the retry from action 14
    success = np.zeros(60, bool)
    success[30:] = True
    traj = SimpleNamespace(action=np.column_stack([np.zeros((60, 4)), jaw]), success=success)
    # states after actions 9, 11 and 14 (1-based: 10, 12, 15), then evenly to the first success (state 31)
    assert _frame_steps(traj, disabled_from=9) == [10, 12, 15, 23, 31]
    assert _frame_steps(traj, disabled_from=-1) == [0, 8, 16, 23, 31]   # the probe never fired: evenly to success


def test_the_reports_name_each_tasks_object_and_keep_needlepicks_measurements_to_it():
    from surrol_data.evaluation.recovery_report import (ATTEMPT_DEFINITION, attempt_definition, object_name,
                                                        probe_definition)

    assert attempt_definition("NeedlePick") == ATTEMPT_DEFINITION and "26 mm" in ATTEMPT_DEFINITION
    peg = attempt_definition("PegTransfer")
    assert "needle" not in peg and "26 mm" not in peg and "the block's grasp point" in peg and "It failed" in peg
    assert "needle" not in probe_definition("GauzeRetrieve") and "near the gauze" in probe_definition("GauzeRetrieve")
    assert object_name("NeedleRings") == "needle" and object_name("PickAndPlace") == "object"

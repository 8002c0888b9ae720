"""The README's Table I section states what the committed study runs say: how many runs it stands on, the success
table, steps and path at epoch 100, the first epoch at ≥ 90 % and the recovery counts. A run committed without the
README following (or a README edited by hand) fails here."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from surrol_data.evaluation.study_report import discover_runs, recovery_rows, table1_estimates

ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "docs" / "results" / "table1" / "runs"
SOURCES = ("script", "novice", "expert")


@pytest.fixture(scope="module")
def section() -> str:
    text = (ROOT / "README.md").read_text()
    start = text.index("## Table I")
    return text[start:text.index("\n## ", start + 1)]


@pytest.fixture(scope="module")
def runs():
    return discover_runs([RUNS])


def _mean_std(est, scale: float = 1.0) -> str:
    return f"{est.mean * scale:.1f} ± {est.std * scale:.1f}"


def _listed(values) -> str:
    """1, 2 and 3: the seeds' figures as a sentence lists them."""
    words = [str(v) for v in values]
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def test_the_run_count_and_the_success_table(section, runs):
    count = "All 12 matched runs are" if len(runs) == 12 else f"{len(runs)} of the 12 matched runs are"
    assert f"**{count} committed" in section
    est = table1_estimates(runs, [50, 100])
    for epoch in (50, 100):
        row = re.search(rf"^\| {epoch} \|(.*)\|$", section, re.M)
        assert row, f"no epoch-{epoch} row in the README's success table"
        ours = [c.strip() for c in row.group(1).split("|")][0::2]
        assert ours == [_mean_std(est[epoch]["success_rate"][s], 100) for s in SOURCES], epoch


def test_steps_path_first_epoch_at_90_and_recovery(section, runs):
    est = table1_estimates(runs, [100])[100]
    steps = " / ".join(f"{est['steps_to_complete'][s].mean:.1f}" for s in SOURCES)
    path = " / ".join(f"{est['economy_of_motion_cm'][s].mean:.1f}" for s in SOURCES)
    flat = " ".join(section.split())
    assert f"Steps to complete at epoch 100: {steps}" in flat
    assert f"economy of motion {path} cm" in flat
    for source in SOURCES:
        firsts = [next(row["epoch"] for row in r.rows if row.get("success_rate", 0) >= 0.9)
                  for r in sorted(runs, key=lambda r: r.seed) if r.source == source]
        assert f"{_listed(firsts)} for the {source}-trained" in flat, source
    first = {source: [next(row["epoch"] for row in r.rows if row.get("success_rate", 0) >= 0.9)
                      for r in runs if r.source == source] for source in SOURCES}
    if "Every human-trained run reaches ≥ 90 % success before any script-trained run" in flat:
        assert max(first["novice"] + first["expert"]) < min(first["script"]), first
    means = ", ".join(f"{np.mean(first[s]):.1f}" for s in SOURCES[1:]) + f" and {np.mean(first['script']):.1f}"
    assert f"(means {means})" in flat
    for row in recovery_rows(runs, 50):
        assert f"{row['source']} {row['recovered']} of {row['first_failed']}" in flat, row


def _first_at_90(run) -> str:
    return str(next((row["epoch"] for row in run.rows if row.get("success_rate", 0) >= 0.9), "never"))


def test_the_natural_study_run_count_and_figures(section):
    runs = discover_runs([ROOT / "docs" / "results" / "table1_natural" / "runs"])
    count = "all 12 runs" if len(runs) == 12 else f"{len(runs)} of its 12 runs"
    flat = " ".join(section.split())
    assert f"{count} committed" in flat
    if len(runs) < 12:
        return   # its figures are summarised once the study is whole
    est = table1_estimates(runs, [50, 100])
    for epoch in (50, 100):
        said = " / ".join(_mean_std(est[epoch]["success_rate"][s], 100) for s in SOURCES)
        assert f"epoch {epoch}: {said} %" in flat, epoch
    natural = flat.split("natural-pace study", 1)[1]
    for source in SOURCES:
        firsts = [_first_at_90(r) for r in sorted(runs, key=lambda r: r.seed) if r.source == source]
        assert f"{_listed(firsts)} for the {source}-trained" in natural, source
    demos = (ROOT / "docs" / "results" / "table1_natural" / "demos.md").read_text()
    steps = {m.group(1): m.group(2) for m in re.finditer(r"^\| (\w+) \| \d+ \| ([\d.]+) \|", demos, re.M)}
    said = ", ".join(f"{source} {steps[source]}" for source in SOURCES)
    assert f"demos of {said} steps" in natural, said
    first = {s: np.mean([int(_first_at_90(r)) for r in runs if r.source == s]) for s in SOURCES}
    means = ", ".join(f"{first[s]:.1f}" for s in SOURCES[:2]) + f" and {first['expert']:.1f}"
    assert f"(means {means})" in natural
    if "the shorter the demos, the sooner the policy reaches 90 %: script first, then expert, then novice" in natural:
        assert float(steps["script"]) < float(steps["expert"]) < float(steps["novice"]), steps
        assert first["script"] < first["expert"] < first["novice"], first
    if "The expert-trained lead the novice-trained at epochs 50 and 100" in natural:
        assert all(est[e]["success_rate"]["expert"].mean > est[e]["success_rate"]["novice"].mean for e in (50, 100))
    at_100 = [r.rows[-1]["success_rate"] for r in runs if r.source == "novice" and r.rows[-1]["epoch"] == 100]
    below = [v for v in at_100 if v < 0.9]
    if "one novice-trained seed has fallen back to" in natural:
        assert len(below) == 1 and f"fallen back to {below[0] * 100:.0f} % at epoch 100" in natural, at_100


def test_the_second_editions_run_count(section):
    """The README says how many of the second edition's runs (docs/results/table1_v2) have finished."""
    folder = ROOT / "docs" / "results" / "table1_v2" / "runs"
    runs = discover_runs([folder]) if any(folder.rglob("metrics.jsonl")) else []
    assert f"{len(runs)} of its 12 matched runs finished" in " ".join(section.split())

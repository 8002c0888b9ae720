"""The README's "Demos or interventions" paragraph states what the committed experiment says
(``docs/results/interventions/results.jsonl``): per task, success after the last round with takeovers and with whole
demos, the human frames each cost, and round 0. Rerunning the experiment without the README following fails here."""

from __future__ import annotations

from pathlib import Path

import pytest

from surrol_data.study.interventions import read_results, recorded_spec, summary_rows

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "docs" / "results" / "interventions"


@pytest.fixture(scope="module")
def paragraph() -> str:
    text = (ROOT / "README.md").read_text()
    start = text.index("**Demos or interventions.**")
    return " ".join(text[start:text.index("\n\n", start)].split())


def test_the_paragraph_states_the_committed_results(paragraph):
    spec = recorded_spec(RESULTS)
    table = summary_rows(read_results(RESULTS), spec)

    def cell(task: str, arm: str, round_: int) -> dict:
        found = [x for x in table if x["task"] == task and x["arm"] == arm and x["round"] == round_]
        assert found and found[0]["seeds"] == len(spec.seeds), f"{task} {arm} round {round_} is not complete"
        return found[0]

    assert f"mean over {len(spec.seeds)} seeds" in paragraph
    assert f"{spec.rounds} rounds" in paragraph and f"{spec.base_demos} of the simulated {spec.skill}" in paragraph
    for task in spec.tasks:
        taken, whole, start = (cell(task, "interventions", spec.rounds), cell(task, "demos", spec.rounds),
                               cell(task, "interventions", 0))
        stated = (f"{task}: {100 * taken['success'].mean:.0f} % with takeovers ({taken['human_frames']:,.0f} human "
                  f"frames), {100 * whole['success'].mean:.0f} % with whole demos ({whole['human_frames']:,.0f}), "
                  f"from {100 * start['success'].mean:.0f} % at round 0")
        assert stated in paragraph

"""The notebooks in notebooks/ run top to bottom: each is executed headless (nbclient, a python3 kernel) in a temporary
copy at SURROL_NOTEBOOK_SIZE=small, with what it writes going to a temporary folder; a cell that raises fails the
test. Notebook 03 reads a tiny table1_quick study made with the study command (conftest), so it goes through the real
records, and once more a folder without runs, where it must say so. The committed notebooks must carry their
outputs (they are what GitHub shows) and stay small."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="the test group installs nbformat (uv run --group test pytest)")
nbclient = pytest.importorskip("nbclient", reason="the test group installs nbclient (uv run --group test pytest)")
pytest.importorskip("ipykernel", reason="the test group installs ipykernel (uv run --group test pytest)")

REPO = Path(__file__).resolve().parents[1]
NOTEBOOKS = REPO / "notebooks"
TOUR, TRAIN, TABLE1 = ("01_demo_sets_tour.ipynb", "02_train_and_compare_sources.ipynb",
                       "03_table1_from_committed_runs.ipynb")
CELL_TIMEOUT_S = 300
MAX_NOTEBOOK_BYTES = 1_500_000


def execute(name: str, tmp_path: Path, monkeypatch, **env: str) -> list[str]:
    """Run a temporary copy of notebook ``name`` (the kernel starts in ``tmp_path``) and return every text its
    outputs hold, for the caller's checks. nbclient raises CellExecutionError, naming the cell, when one fails."""
    monkeypatch.setenv("SURROL_NOTEBOOK_SIZE", "small")
    monkeypatch.setenv("SURROL_NOTEBOOK_OUT", str(tmp_path / "out"))
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    copy = tmp_path / name
    nbformat.write(nb, copy)
    client = nbclient.NotebookClient(nb, timeout=CELL_TIMEOUT_S, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    nbformat.write(nb, copy)    # left beside the outputs for a look after a failed check
    texts = []
    for cell in nb.cells:
        for output in cell.get("outputs", []):
            texts.append(output.get("text", ""))
            texts += [v for k, v in output.get("data", {}).items() if k.startswith("text/") and isinstance(v, str)]
    return texts


@pytest.fixture(scope="module")
def quick_study(table1_quick_partial) -> Path:
    """A two-run table1_quick study (script/0, novice/0), made by the study command as a user would (conftest: one
    per session, shared with test_study_runs)."""
    assert len(list((table1_quick_partial / "runs").rglob("metrics.jsonl"))) == 2
    return table1_quick_partial


@pytest.mark.timeout(900)
def test_demo_sets_tour_runs(tmp_path, monkeypatch):
    texts = execute(TOUR, tmp_path, monkeypatch)
    assert (tmp_path / "out" / "01_demo_sets_tour.rrd").stat().st_size > 0
    assert any("Expert benchmark" in t for t in texts)


@pytest.mark.timeout(900)
def test_train_and_compare_sources_runs_small(tmp_path, monkeypatch):
    texts = execute(TRAIN, tmp_path, monkeypatch)
    assert any("SIZE=small" in t for t in texts)
    assert any("oracle (reference)" in t for t in texts)


@pytest.mark.timeout(900)
def test_table1_notebook_reads_a_study(quick_study, tmp_path, monkeypatch):
    texts = execute(TABLE1, tmp_path, monkeypatch, SURROL_TABLE1_DIR=str(quick_study))
    assert any("2 finished runs" in t for t in texts)
    assert any("Success rate (%)" in t for t in texts)             # the Table I rows
    assert any("the same Table I" in t for t in texts)             # as the study's own report.md
    assert (tmp_path / "out" / "03_learning_curves.png").stat().st_size > 0


@pytest.mark.timeout(300)
def test_table1_notebook_without_runs_says_so(tmp_path, monkeypatch):
    texts = execute(TABLE1, tmp_path, monkeypatch, SURROL_TABLE1_DIR=str(tmp_path / "no_study_yet"))
    assert any("No study runs are committed" in t for t in texts)


@pytest.mark.parametrize("name", [TOUR, TRAIN, TABLE1])
def test_committed_notebooks_carry_their_outputs(name):
    """GitHub shows the committed outputs: every code cell ran, none failed, and the file stays small."""
    path = NOTEBOOKS / name
    assert path.stat().st_size < MAX_NOTEBOOK_BYTES, f"{name}: {path.stat().st_size} bytes; keep outputs small"
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.get("execution_count") for c in code), f"{name}: not executed; run it and commit the outputs"
    errors = [o for c in code for o in c.outputs if o.output_type == "error"]
    assert not errors, f"{name}: committed with an error output: {json.dumps(errors[0])[:500]}"

"""Issue 28: a dataset path that is not there (or is no dataset at all) is said to be so, not "damaged" with a
suggestion to `repair` it."""

import pytest
from typer.testing import CliRunner

from surrol_data.cli import app


def _said(*args):
    run = CliRunner().invoke(app, list(args))
    return run.exit_code, " ".join(run.output.split())


def _unspaced(text: str) -> str:
    # Rich folds a word longer than the line (a path: a worker's tmp_path is 10 characters longer) mid-word
    return "".join(text.split())


def test_info_on_a_missing_folder_says_it_does_not_exist(tmp_path):
    missing = tmp_path / "NeedlePick_demos"
    code, said = _said("info", str(missing))
    assert code == 2
    assert _unspaced(f"{missing} does not exist") in _unspaced(said) and "surrol-data collect" in said
    assert "damaged" not in said and "repair" not in said


@pytest.mark.parametrize("make, expected", [
    (lambda p: p.write_text("x"), "is a file"),
    (lambda p: p.mkdir(), "is not a dataset (it has no meta/ folder)"),
])
def test_info_on_something_that_is_no_dataset_says_what_it_is(tmp_path, make, expected):
    path = tmp_path / "thing"
    make(path)
    code, said = _said("info", str(path))
    assert code == 2 and expected in said and "damaged" not in said and "repair" not in said


def test_every_dataset_command_says_so(tmp_path):
    missing = str(tmp_path / "nowhere")
    for args in (["assess", missing], ["view", missing, "--out", str(tmp_path / "v.rrd")],
                 ["train-bc", missing, "--out", str(tmp_path / "p.pt")]):
        code, said = _said(*args)
        assert code == 2 and "does not exist" in said and "damaged" not in said, (args, said)

"""Issue 28: messages are printed as text, not Rich markup: an install hint keeps its `[export]`."""

from typer.testing import CliRunner

from surrol_data import cli
from surrol_data.extras import MissingExtra, install_hint


def test_a_missing_extra_hint_keeps_the_extra_in_brackets(monkeypatch):
    def missing(module):
        raise MissingExtra(install_hint(module))

    monkeypatch.setattr("surrol_data.extras.require", missing)
    run = CliRunner().invoke(cli.app, ["gui"])
    said = " ".join(run.output.split())
    assert run.exit_code == 2
    assert "pip install 'surrol-data[render]'" in said and "uv sync --extra render" in said


def test_errors_and_notes_print_brackets_as_written(capsys):
    text = "pip install 'surrol-data[export]' or [bold]not bold[/bold]"
    cli._note(text)
    assert text in " ".join(capsys.readouterr().err.split())
    run = CliRunner().invoke(cli.app, ["info", "missing[export]"])
    assert "missing[export] does not exist" in " ".join(run.output.split())

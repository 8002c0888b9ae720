"""One grammar for every command: positional datasets, ``--out`` for what is written, ``--episodes`` as indices
with ranges and ``--num-episodes`` as a count, errors in command-line terms, progress for long work."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.datasets.episode_ranges import parse_episode_ranges


@pytest.mark.parametrize("spec, expected", [
    ("0", [0]), ("0,3,5-9", [0, 3, 5, 6, 7, 8, 9]), (" 2 , 2,1-2 ", [2, 1]), ("4-4", [4]),
])
def test_episode_ranges(spec, expected):
    assert parse_episode_ranges(spec) == expected


@pytest.mark.parametrize("spec, message", [
    ("3-1", "FIRST-LAST"), ("a", "neither"), ("-2", "FIRST-LAST|neither"), (",", "names no episode"),
])
def test_episode_ranges_refuse_what_is_not_indices(spec, message):
    with pytest.raises(ValueError, match=message):
        parse_episode_ranges(spec)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("grammar") / "reach"
    collect_script("NeedleReach", 3, root, max_steps=3, keep_failures=True, progress=False)
    return root


def _run(*args: str):
    run = CliRunner().invoke(app, list(args))
    return run.exit_code, " ".join(run.output.split())


def test_errors_speak_in_flags_not_python_arguments(small, tmp_path):
    code, said = _run("collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "1",
                      "--out", str(small))
    assert code == 2 and "--append" in said and "append=True" not in said
    code, said = _run("split", str(small), "--out", str(tmp_path / "s"), "--valid-fraction", "1.5")
    assert code == 2 and "--valid-fraction" in said and "valid_fraction" not in said
    code, said = _run("view", str(small), "--episodes", "0,7-9", "--out", str(tmp_path / "v.rrd"))
    assert code == 2 and "[7, 8, 9] are not in" in said
    code, said = _run("filter", str(small), "--out", str(tmp_path / "f"))
    assert code == 2 and "--where" in said and "--episodes" in said
    code, said = _run("collect", "--source", "script", "--task", "NeedleReach", "--out", str(tmp_path / "c"))
    assert code == 2 and "--num-episodes" in said
    code, said = _run("collect", "--source", "script", "--task", "NeedleReach", "--num-episodes", "1",
                      "--camera-size", "big", "--out", str(tmp_path / "c"))
    assert code == 2 and "WIDTHxHEIGHT" in said


def test_episodes_are_indices_everywhere_and_the_old_count_still_works(small, tmp_path):
    from surrol_data.datasets.reader import DatasetReader

    code, said = _run("filter", str(small), "--episodes", "0,2", "--out", str(tmp_path / "f"))
    assert code == 0, said
    assert list(DatasetReader(tmp_path / "f").episodes["seed"]) == [0, 2]
    code, said = _run("filter", str(small), "--episodes", "0-2", "--where", "seed >= 1", "--out", str(tmp_path / "g"))
    assert code == 0 and list(DatasetReader(tmp_path / "g").episodes["seed"]) == [1, 2]
    code, said = _run("collect", "--source", "script", "--task", "NeedleReach", "--episodes", "1", "--max-steps", "2",
                      "--keep-failures", "--out", str(tmp_path / "old"))
    assert code == 0 and "deprecated" in said and "--num-episodes 1" in said
    assert len(DatasetReader(tmp_path / "old")) == 1


def test_validate_reports_each_stage(small):
    from surrol_data.datasets.validate import STAGES, validate_dataset

    seen: list[str] = []
    assert validate_dataset(small, progress=seen.append) == []
    assert seen == list(STAGES)

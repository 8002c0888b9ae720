"""Demo assessment on a real dataset recorded by simulated expert and novice operators and the script oracle."""

import math

import pandas as pd
import pytest

from surrol_data.evaluation.assess import (assess_dataset, assessment_markdown, expert_benchmark, meets,
                                           proficient_at, write_assessment)


@pytest.fixture(scope="module")
def mixed_dataset(tmp_path_factory):
    from surrol_data.collect.haptic_source import collect_haptic
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("assess") / "NeedlePick_mixed"
    collect_haptic("NeedlePick", 2, root, device="operator", skill="expert", operator_id="e1", progress=False)
    collect_haptic("NeedlePick", 2, root, device="operator", skill="novice", operator_id="n1", append=True,
                   seed=100, progress=False)
    collect_script("NeedlePick", 2, root, append=True, progress=False)
    return root


def test_assessment_groups_operators_and_skills_with_an_expert_benchmark(mixed_dataset, tmp_path):
    result = assess_dataset(mixed_dataset)
    assert len(result.episodes) == 6
    assert set(result.operators["skill"]) == {"expert", "novice", "scripted"}
    assert set(result.skills["group"]) == {"all expert", "all novice", "all scripted"}
    experts = result.episodes[result.episodes["skill"] == "expert"]
    assert result.benchmark["steps_to_success"] == pytest.approx(experts["steps_to_success"].mean())
    # haptic episodes carry device traces: their smoothness comes from the device, the script's from the tip
    assert set(result.episodes[result.episodes["source"] == "haptic"]["smoothness_source"]) == {"device"}
    assert set(result.episodes[result.episodes["source"] == "script"]["smoothness_source"]) == {"tip"}
    md = assessment_markdown(result)
    assert "Expert benchmark" in md and "| e1 (haptic) | expert | 2 |" in md
    files = write_assessment(result, tmp_path / "out")
    assert files["figure"].stat().st_size > 10_000 and len(pd.read_csv(files["episodes"])) == 6


def test_benchmark_rules_on_hand_made_rows():
    rows = pd.DataFrame({"skill": ["expert", "expert", "novice"], "success": [True, True, True],
                         "steps_to_success": [40.0, 60.0, 55.0], "path_length_cm": [10.0, 12.0, 10.5],
                         "errors": [0.0, 1.0, 0.0]})
    bench = expert_benchmark(rows)
    assert bench == {"steps_to_success": 50.0, "path_length_cm": 11.0, "errors": 0.5}
    assert meets(rows.iloc[0], bench) and not meets(rows.iloc[1], bench) and not meets(rows.iloc[2], bench)
    failed = rows.iloc[0].copy()
    failed["success"] = False
    assert not meets(failed, bench)
    unknown_errors = rows.iloc[0].copy()
    unknown_errors["errors"] = math.nan          # not recorded: judged on the metrics that are
    assert meets(unknown_errors, bench)
    assert expert_benchmark(rows[rows["skill"] == "novice"]) == {}


@pytest.mark.parametrize("flags, at", [([True, True], 1), ([False, True, False, True, True], 4),
                                        ([True, False, True], 0), ([], 0)])
def test_proficiency_needs_two_consecutive_trials(flags, at):
    assert proficient_at(flags) == at


def test_assess_and_report_commands(mixed_dataset, tmp_path):
    from typer.testing import CliRunner

    from surrol_data.cli import app

    runner = CliRunner()
    result = runner.invoke(app, ["assess", str(mixed_dataset), "--out", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert "Expert benchmark" in result.output and (tmp_path / "a" / "assessment.png").is_file()
    missing = runner.invoke(app, ["report", str(tmp_path / "no_runs_here"), "--out", str(tmp_path / "r")])
    assert missing.exit_code == 2 and "does not exist" in " ".join(missing.output.split())   # rich wraps lines
    bad = runner.invoke(app, ["report", str(tmp_path), "--out", str(tmp_path / "r"), "--epochs", "fifty"])
    assert bad.exit_code == 2 and "--epochs takes whole numbers" in " ".join(bad.output.split())


def test_info_and_assess_give_one_ldlj(mixed_dataset):
    """`info` and `assess` printed two LDLJ values for one dataset (info from the tip path, assess from the device
    trace): both measure an episode's smoothness one way, on its device trace where it has one."""
    import numpy as np

    from surrol_data.datasets.info import _smoothness, skill_breakdown
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.evaluation.assess import score_episodes

    reader = DatasetReader(mixed_dataset)
    scored = score_episodes(reader)
    ok = scored[scored["success"]]
    assert set(ok["smoothness_source"]) == {"device", "tip"}   # haptic episodes have traces, scripted ones not
    np.testing.assert_allclose(_smoothness(reader, [int(e) for e in ok["episode_index"]]),
                               ok["log_dimensionless_jerk"].to_numpy(), rtol=1e-9)
    info_groups = {(g["source"], g["skill"]): g["mean_ldlj"] for g in skill_breakdown(mixed_dataset)}
    for (source, skill), rows in ok.groupby(["source", "skill"]):
        assert info_groups[(source, skill)] == pytest.approx(rows["log_dimensionless_jerk"].mean())

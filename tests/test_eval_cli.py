"""`surrol-data eval`: unseen seeds by default, a record of task, policy and seeds, and no `nan` in tables."""

import json

from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.evaluation.rollout import EVAL_SEED_BASE


def test_eval_records_task_policy_and_unseen_seeds(tmp_path):
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, ["eval", "--task", "NeedleReach", "--num-episodes", "2", "--max-steps", "3",
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads(out.read_text())      # strict JSON: a metric without a value is null, not NaN
    assert (record["task"], record["env_id"], record["policy"]) == ("NeedleReach", "SurRoL/NeedleReach-v0", "oracle")
    assert record["seeds"] == [EVAL_SEED_BASE, EVAL_SEED_BASE + 1] and len(record["episodes"]) == 2
    # 3 steps are too few to reach the needle: no success, so no steps-to-complete — shown as "–", stored as null
    assert record["summary"]["success_rate"] == 0.0 and record["summary"]["mean_steps_to_success"] is None
    assert "nan" not in result.output and "–" in result.output


def test_eval_scores_every_run_of_a_sweep_folder(tmp_path):
    """`--policy FOLDER` evaluates the policy.pt of every run under it (a sweep's runs), one record each."""
    from surrol_data.algos.bc import BCConfig, BCPolicy
    from surrol_data.algos.networks import DeterministicActor
    from surrol_data.algos.normalizer import Normalizer

    for seed in (0, 1):
        actor = DeterministicActor(7, 3, 5, (16,))
        BCPolicy(actor, Normalizer(7), Normalizer(3), BCConfig(hidden_sizes=(16,))).save(
            tmp_path / "sweep" / f"seed{seed}" / "policy.pt")
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, ["eval", "--task", "NeedleReach", "--policy", str(tmp_path / "sweep"),
                                      "--episodes", "1", "--max-steps", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    records = json.loads(out.read_text())
    assert [r["policy"] for r in records] == [str(tmp_path / "sweep" / f"seed{s}" / "policy.pt") for s in (0, 1)]
    assert all(r["seeds"] == [EVAL_SEED_BASE] for r in records)
    none = tmp_path / "empty"
    none.mkdir()
    failed = CliRunner().invoke(app, ["eval", "--task", "NeedleReach", "--policy", str(none)])
    assert failed.exit_code == 2 and "no policy.pt" in " ".join(failed.output.split())

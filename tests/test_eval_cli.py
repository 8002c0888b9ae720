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

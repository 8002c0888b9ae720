"""A robomimic policy trained on our export is scored in our Gymnasium env by `surrol-data eval --policy
robomimic:CKPT` (robomimic's own policy API, `policy_from_checkpoint`; not robomimic's rollouts, which need the old
`gym`)."""

import json

import pytest
from typer.testing import CliRunner

pytest.importorskip("robomimic", reason="needs robomimic (the test group installs it)")


@pytest.mark.slow
def test_a_two_epoch_robomimic_bc_policy_trained_on_the_export_is_scored_by_eval(tmp_path):
    import torch
    from robomimic.config import config_factory
    from robomimic.scripts.train import train

    from surrol_data.cli import app
    from surrol_data.collect.script_source import collect_script
    from surrol_data.datasets.export_robomimic import OBS_KEYS, export_robomimic

    collect_script("NeedleReach", 4, tmp_path / "ds", progress=False)
    hdf5 = export_robomimic(tmp_path / "ds", tmp_path / "reach.hdf5", valid_fraction=0.25, progress=False)
    config = config_factory("bc")
    with config.values_unlocked():
        config.train.data = str(hdf5)
        config.train.output_dir = str(tmp_path / "robomimic")
        config.experiment.name = "bc"
        config.train.num_epochs = 2
        config.experiment.epoch_every_n_steps = 5
        config.experiment.validate = False
        config.experiment.rollout.enabled = False      # robomimic's rollouts: the old gym; ours score it below
        config.experiment.save.enabled = True
        config.experiment.save.every_n_epochs = 2
        config.experiment.logging.log_tb = False
        config.experiment.logging.log_wandb = False
        config.observation.modalities.obs.low_dim = list(OBS_KEYS)
        config.train.batch_size = 16
        config.train.cuda = False
        config.algo.actor_layer_dims = (32, 32)
    train(config, device=torch.device("cpu"))
    checkpoint = next((tmp_path / "robomimic").rglob("model_epoch_2.pth"))

    record = tmp_path / "eval.json"
    run = CliRunner().invoke(app, ["eval", "--task", "NeedleReach", "--policy", f"robomimic:{checkpoint}",
                                   "--num-episodes", "2", "--max-steps", "10", "--out", str(record)])
    assert run.exit_code == 0, run.output
    result = json.loads(record.read_text())
    assert result["policy"] == f"robomimic:{checkpoint}" and result["task"] == "NeedleReach"
    assert [e["steps"] for e in result["episodes"]] == [10, 10]
    assert all(e["path_length_full_cm"] > 0 for e in result["episodes"])   # the policy moved the tool


def test_a_robomimic_spec_that_is_not_a_checkpoint_is_one_error(tmp_path):
    from surrol_data.cli import app

    run = CliRunner().invoke(app, ["eval", "--task", "NeedleReach", "--policy", f"robomimic:{tmp_path / 'no.pth'}"])
    assert run.exit_code == 2 and "is not a robomimic checkpoint file" in " ".join(run.output.split())

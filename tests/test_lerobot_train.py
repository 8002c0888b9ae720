"""LeRobot's own training entry point trains an ACT policy on a dataset made by `surrol-data collect` (no key
renamed, nothing downloaded), and the policy is evaluated in our env by `surrol-data eval --policy lerobot:DIR`
(proficiency metrics) and by `lerobot-eval` through the surrol env plugin.

Slow: three fresh processes that each import torch and lerobot, ~2–4 min on the shared 2-core machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

BIN = Path(sys.executable).parent
ACT_SMALL = ["--policy.type=act", "--policy.device=cpu", "--policy.push_to_hub=false",
             "--policy.pretrained_backbone_weights=null",  # state-only: no vision backbone, nothing to fetch
             "--policy.chunk_size=10", "--policy.n_action_steps=10", "--policy.dim_model=64",
             "--policy.dim_feedforward=128", "--policy.n_heads=4", "--policy.latent_dim=16"]


def _run(args: list, env: dict, timeout: int = 900) -> str:
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, env=env, timeout=timeout)
    assert done.returncode == 0, f"{args[0]} failed:\n{done.stdout[-3000:]}\n{done.stderr[-5000:]}"
    return done.stdout + done.stderr


def test_act_trained_by_lerobot_train_runs_in_surrol_eval_and_lerobot_eval(tmp_path):
    torch_home = tmp_path / "torch_home"
    torch_home.mkdir()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TORCH_HOME": str(torch_home), "OMP_NUM_THREADS": "1",
           "HF_LEROBOT_HOME": str(tmp_path / "lerobot_home"), "WANDB_MODE": "disabled"}
    data, out = tmp_path / "needle_pick", tmp_path / "act"
    _run([BIN / "surrol-data", "collect", "--source", "script", "--task", "NeedlePick", "--episodes", 2,
          "--out", data], env)

    _run([BIN / "lerobot-train", "--dataset.repo_id=local/needle_pick", f"--dataset.root={data}",
          "--dataset.video_backend=pyav", *ACT_SMALL, "--steps=6", "--batch_size=4", "--num_workers=0",
          f"--output_dir={out}", "--save_freq=6", "--log_freq=2", "--wandb.enable=false"], env)
    model = out / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((model / "config.json").read_text())
    assert config["type"] == "act" and config["pretrained_backbone_weights"] is None
    # trained on the dataset's own keys: the state and the object/goal state, nothing renamed
    assert set(config["input_features"]) == {"observation.state", "observation.environment_state"}
    assert config["input_features"]["observation.environment_state"]["type"] == "ENV"
    step = json.loads((out / "checkpoints" / "last" / "training_state" / "training_step.json").read_text())
    assert step["step"] == 6
    assert not any(torch_home.iterdir())  # no pretrained weights were fetched

    record = tmp_path / "eval.json"
    output = _run([BIN / "surrol-data", "eval", "--task", "NeedlePick", "--policy", f"lerobot:{out}",
                   "--episodes", 2, "--max-steps", 8, "--out", record], env)
    assert "lerobot:" in output
    result = json.loads(record.read_text())
    assert result["policy"] == f"lerobot:{out}" and result["task"] == "NeedlePick"
    assert min(result["seeds"]) >= 1_000_000_000  # never a demo's seed
    assert [e["steps"] for e in result["episodes"]] == [8, 8]
    assert all(e["path_length_cm"] > 0 for e in result["episodes"])  # the policy moved the tool

    lerobot_eval = tmp_path / "lerobot_eval"
    _run([BIN / "lerobot-eval",   # no --env.discover_packages_path: the lerobot_env_surrol plugin registers it
          "--env.type=surrol", "--env.task=NeedlePick", "--env.episode_length=6", f"--policy.path={model}",
          "--policy.device=cpu", "--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={lerobot_eval}"], env)
    overall = json.loads((lerobot_eval / "eval_info.json").read_text())["overall"]
    assert overall["n_episodes"] == 1 and 0.0 <= overall["pc_success"] <= 100.0

"""A LeRobot policy saved the way lerobot-train saves its checkpoints runs in our env (`lerobot:DIR`), and the
lerobot-eval env plugin hands lerobot the dataset's own keys. (Training with lerobot-train itself is the slow
test_lerobot_train.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from surrol_data.datasets.trajectory import Trajectory

OBS, GOAL, ACT = 19, 3, 5  # NeedlePick's dimensions


def _traj(seed: int, T: int = 12, camera: tuple[int, int] | None = None) -> Trajectory:
    rng = np.random.default_rng(seed)
    images = {} if camera is None else {"endoscope": rng.integers(0, 255, (T + 1, *camera, 3), dtype=np.uint8)}
    return Trajectory(images=images,
        observation=rng.standard_normal((T + 1, OBS)).astype(np.float32),
        achieved_goal=rng.standard_normal((T + 1, GOAL)).astype(np.float32),
        desired_goal=rng.standard_normal((T + 1, GOAL)).astype(np.float32),
        action=rng.uniform(-1, 1, (T, ACT)).astype(np.float32), reward=-np.ones(T, np.float32),
        success=np.zeros(T, bool), terminated=np.zeros(T, bool),
        tip_position=rng.standard_normal((T + 1, 1, 3)).astype(np.float32),
        jaw_angle=rng.uniform(0, 1, (T + 1, 1)).astype(np.float32))


def _save_act(base, camera: tuple[int, int] | None = None):
    """An untrained ACT built from a dataset's metadata and stats, saved with its processors (what a
    lerobot-train checkpoint's pretrained_model folder holds) under ``base``."""
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
    from lerobot.policies import ACTConfig, make_policy, make_pre_post_processors

    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.hub_offline import hub_offline
    from surrol_data.datasets.schema import frame_features

    root = base / "data"
    features = frame_features(OBS, GOAL, ACT, 1, cameras={"endoscope": camera} if camera else None)
    with DatasetRecorder(root, features=features, task="NeedlePick", env_id="SurRoL/NeedlePick-v0",
                         task_description="pick", handle_signals=False) as rec:
        for i in range(2):
            rec.record(_traj(i, camera=camera), {"source": "script", "device": "none", "skill": "scripted", "seed": i})
    with hub_offline():
        meta = LeRobotDatasetMetadata("local/data", root=root)
    config = ACTConfig(device="cpu", pretrained_backbone_weights=None, chunk_size=4, n_action_steps=4, dim_model=32,
                       dim_feedforward=64, n_heads=2, latent_dim=8, n_encoder_layers=1)
    policy = make_policy(config, ds_meta=meta)
    pre, post = make_pre_post_processors(config, dataset_stats=meta.stats)
    out = base / "checkpoints" / "last" / "pretrained_model"
    for part in (policy, pre, post):
        part.save_pretrained(out)
    return base


@pytest.fixture(scope="module")
def act_dir(tmp_path_factory):
    return _save_act(tmp_path_factory.mktemp("act"))


def test_lerobot_policy_rolls_out_in_our_env_and_restarts_its_chunk_each_episode(act_dir, monkeypatch):
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401
    from surrol_data.evaluation.lerobot_policy import LerobotPolicy
    from surrol_data.algos.policies import load_policy
    from surrol_data.evaluation.rollout import evaluate, rollout

    policy = load_policy(f"lerobot:{act_dir}")  # the lerobot-train output folder: its last checkpoint
    assert isinstance(policy, LerobotPolicy) and policy.path.name == "pretrained_model"
    resets = []
    monkeypatch.setattr(policy.policy, "reset", lambda original=policy.policy.reset: (resets.append(1), original()))
    result = evaluate("SurRoL/NeedlePick-v0", policy, episodes=2, max_steps=6, progress=False, keep_trajectories=True)
    assert len(resets) == 2 and [len(t) for t in result.trajectories] == [6, 6]
    assert np.isfinite(result.trajectories[0].action).all()

    # after 6 steps of a 4-action chunk, 2 actions are queued: a new episode must not use them
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=6)
    try:
        second = rollout(env, policy, seed=result.seeds[1])
        fresh = load_policy(f"lerobot:{act_dir}")
        obs, _ = env.reset(seed=result.seeds[1])
        assert np.allclose(second.action[0], np.clip(fresh(obs), -1, 1), atol=1e-6)
    finally:
        env.close()


def test_lerobot_policy_refuses_a_task_of_other_dimensions(act_dir):
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401
    from surrol_data.evaluation.lerobot_policy import LerobotPolicy, pretrained_dir

    policy = LerobotPolicy(act_dir)
    env = gym.make("SurRoL/NeedleReach-v0")
    try:
        obs, _ = env.reset(seed=0)
        with pytest.raises(ValueError, match=r"observation.state of shape \(7,\).*trained on \(19,\)"):
            policy(obs)
    finally:
        env.close()
    with pytest.raises(FileNotFoundError, match="holds no LeRobot policy"):
        pretrained_dir(act_dir / "nowhere")


def test_a_policy_trained_on_the_endoscope_video_gets_the_camera_at_its_size(tmp_path):
    from surrol_data.algos.policies import load_policy
    from surrol_data.evaluation.rollout import evaluate

    policy = load_policy(f"lerobot:{_save_act(tmp_path, camera=(24, 32))}")
    assert policy.input_shapes["observation.images.endoscope"] == (3, 24, 32)
    assert policy.env_kwargs == {"camera": True, "camera_size": (32, 24)}  # gym.make takes (width, height)
    result = evaluate("SurRoL/NeedlePick-v0", policy, episodes=1, max_steps=2, progress=False)
    assert result.proficiency[0].steps == 2


def test_lerobot_eval_plugin_gives_the_dataset_keys():
    from lerobot.envs.configs import EnvConfig
    from lerobot.envs.utils import env_to_policy_features, preprocess_observation

    from surrol_data.evaluation.lerobot_env import SurrolEnv

    assert EnvConfig.get_choice_class("surrol") is SurrolEnv  # registered on import, as lerobot's parser does
    config = SurrolEnv(task="NeedlePick")
    features = env_to_policy_features(config)
    assert {k: tuple(ft.shape) for k, ft in features.items()} == {
        "action": (5,), "observation.state": (19,), "observation.environment_state": (6,)}
    vec = config.create_envs(n_envs=1)["surrol"][0]
    try:
        obs, _ = vec.reset(seed=[5])
        batch = preprocess_observation(obs)
        assert set(batch) == {"observation.state", "observation.environment_state"}
        assert batch["observation.environment_state"].shape == (1, 6)
        assert list(vec.call("task_description"))[0].startswith("Pick up the needle")
        _, _, _, _, info = vec.step(np.zeros((1, 5), np.float32))
        assert "is_success" in info  # what lerobot-eval counts
    finally:
        vec.close()

    camera = SurrolEnv(task="NeedlePick", camera_width=32, camera_height=24)
    assert tuple(env_to_policy_features(camera)["observation.images.endoscope"].shape) == (3, 24, 32)
    vec = camera.create_envs(n_envs=1)["surrol"][0]
    try:
        obs, _ = vec.reset(seed=[5])
        image = preprocess_observation(obs)["observation.images.endoscope"]
        assert image.shape == (1, 3, 24, 32) and 0.0 <= float(image.min()) <= float(image.max()) <= 1.0
    finally:
        vec.close()


def test_lerobot_eval_of_a_camera_policy_without_the_camera_size_takes_the_policys(tmp_path, monkeypatch):
    """`lerobot-eval --env.type=surrol --policy.path=P` of a policy trained on the endoscope video, without
    --env.camera_width/height: the env renders the image at the policy's size (not `KeyError:
    'observation.images.endoscope'` deep in lerobot)."""
    import sys

    from lerobot.envs.utils import env_to_policy_features

    from surrol_data.evaluation.lerobot_env import SurrolEnv

    pretrained = _save_act(tmp_path, camera=(24, 32)) / "checkpoints" / "last" / "pretrained_model"
    monkeypatch.setattr(sys, "argv", ["lerobot-eval", "--env.type=surrol", "--env.task=NeedlePick",
                                      f"--policy.path={pretrained}"])
    config = SurrolEnv(task="NeedlePick")
    assert (config.camera_width, config.camera_height) == (32, 24)
    assert tuple(env_to_policy_features(config)["observation.images.endoscope"].shape) == (3, 24, 32)
    monkeypatch.setattr(sys, "argv", ["lerobot-eval", f"--policy.path={tmp_path / 'elsewhere'}"])
    assert SurrolEnv(task="NeedlePick").camera_width == 0   # a policy without the image (or none there): no camera


def test_a_camera_size_other_than_the_policys_is_refused(tmp_path, monkeypatch):
    import sys

    from surrol_data.evaluation.lerobot_env import SurrolEnv

    pretrained = _save_act(tmp_path, camera=(24, 32)) / "checkpoints" / "last" / "pretrained_model"
    monkeypatch.setattr(sys, "argv", ["lerobot-eval", "--env.type=surrol", f"--policy.path={pretrained}"])
    with pytest.raises(ValueError, match=r"64x48 differ from the 32x24 endoscope images the policy was trained on"):
        SurrolEnv(task="NeedlePick", camera_width=64, camera_height=48)
    assert SurrolEnv(task="NeedlePick", camera_width=32, camera_height=24).camera_width == 32   # the same: fine


def test_lerobot_eval_finds_the_surrol_env_with_no_flag_and_evaluates_an_act_policy(act_dir, tmp_path):
    """The `lerobot_env_surrol` distribution (a workspace member, installed by `uv sync`) is what LeRobot's
    register_third_party_plugins imports: `lerobot-eval --env.type=surrol --policy.path=...` in a fresh process,
    without --env.discover_packages_path, evaluates the ACT policy."""
    import importlib.metadata
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    assert importlib.metadata.distribution("lerobot_env_surrol").metadata["Name"] == "lerobot_env_surrol"
    out = tmp_path / "eval"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_LEROBOT_HOME": str(tmp_path / "home"), "OMP_NUM_THREADS": "1"}
    run = subprocess.run([str(Path(sys.executable).parent / "lerobot-eval"), "--env.type=surrol",
                          "--env.task=NeedlePick", "--env.episode_length=3",
                          f"--policy.path={act_dir / 'checkpoints' / 'last' / 'pretrained_model'}",
                          "--policy.device=cpu", "--eval.n_episodes=1", "--eval.batch_size=1", f"--output_dir={out}"],
                         capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-4000:]
    overall = json.loads((out / "eval_info.json").read_text())["overall"]
    assert overall["n_episodes"] == 1


def test_the_documented_act_command_plans_chunks_that_fit_the_data():
    """docs/training.md's lerobot-train command: ACT's chunks (default 100 steps, made for 50 Hz) must fit data at
    5 frames/s whose episodes last at most 50 steps: at most 2 s of actions per chunk, replanned within it."""
    import re
    from pathlib import Path

    from surrol_data.datasets.schema import FPS
    from surrol_data.envs import DEFAULT_MAX_EPISODE_STEPS

    text = (Path(__file__).resolve().parents[1] / "docs" / "training.md").read_text().replace("\\\n", " ")
    command = next(line for line in text.splitlines() if "lerobot-train" in line and "--policy.type=act" in line)
    value = lambda name: int(re.search(rf"--policy\.{name}=(\d+)", command)[1])  # noqa: E731
    chunk, steps = value("chunk_size"), value("n_action_steps")
    assert chunk <= 2 * FPS and chunk <= DEFAULT_MAX_EPISODE_STEPS["NeedlePick"] // 2
    assert 1 <= steps <= chunk

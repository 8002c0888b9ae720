"""The Table I study: matched demo sources (paced oracle, matched operator profiles), the study configs, and the
whole pipeline (demo sets → batched training → report) on table1_quick."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.collect.haptic_source import collect_haptic
from surrol_data.collect.operator import MATCHED_PROFILES, PROFILES, operator_params
from surrol_data.collect.script_source import SCRIPT_SPEED_MATCHED, PacedOracle
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.evaluation.rollout import ORACLE, rollout
from surrol_data.study import load_spec


def test_matched_profiles_are_the_same_people_at_another_pace():
    assert set(MATCHED_PROFILES) == {"expert_matched", "novice_matched"}
    for name, params in MATCHED_PROFILES.items():
        assert params.skill == name.split("_")[0]
    natural, matched = operator_params("expert", "ann"), operator_params("expert_matched", "ann")
    assert matched.skill == "expert"
    # one identity draw: a parameter the matched profile leaves alone is the same person's value
    assert matched.tremor_hz == natural.tremor_hz and matched.reaction_time_s == natural.reaction_time_s
    assert matched.speed_fraction < natural.speed_fraction          # the matched expert works slower
    # skill still shows in the matched profiles where the paper's non-experts differed
    e, n = MATCHED_PROFILES["expert_matched"], MATCHED_PROFILES["novice_matched"]
    assert n.tremor_mm > e.tremor_mm and n.hesitation_probability > e.hesitation_probability
    assert n.depth_bias_mm > e.depth_bias_mm and e.anticipates_clutch and not n.anticipates_clutch
    assert PROFILES["novice"].frame_rotation_spread_deg > n.frame_rotation_spread_deg


def test_profile_must_fit_the_skill_and_the_device(tmp_path):
    with pytest.raises(ValueError, match="expert profile, but --skill is 'novice'"):
        collect_haptic("NeedlePick", 1, tmp_path / "x", device="operator", skill="novice", profile="expert_matched")
    with pytest.raises(ValueError, match="needs --device operator"):
        collect_haptic("NeedlePick", 1, tmp_path / "x", device="keyboard", skill="novice", profile="novice_matched")
    with pytest.raises(ValueError, match="unknown operator profile"):
        collect_haptic("NeedlePick", 1, tmp_path / "x", device="operator", skill="novice", profile="novice_slow")
    assert not (tmp_path / "x").exists()


def test_paced_oracle_takes_longer_along_the_same_path():
    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=150)
    try:
        fast = trajectory_proficiency(rollout(env, ORACLE, 3))
        slow = trajectory_proficiency(rollout(env, PacedOracle(env, SCRIPT_SPEED_MATCHED), 3))
    finally:
        env.close()
    assert fast.success and slow.success
    assert slow.steps_to_success > 2.5 * fast.steps_to_success
    assert slow.path_length_cm == pytest.approx(fast.path_length_cm, rel=0.1)
    with pytest.raises(ValueError, match="oracle speed"):
        PacedOracle(env, 0.0)


def test_paced_oracle_keeps_the_jaw_command():
    class Env:
        class unwrapped:  # noqa: N801  (stands for env.unwrapped)
            @staticmethod
            def oracle_action(obs):
                return np.array([1.0, -1.0, 0.5, 0.4, -0.5, 1.0, 1.0, 1.0, 1.0, 0.5], np.float32)

    action = PacedOracle(Env, 0.5)({})
    np.testing.assert_allclose(action, [0.5, -0.5, 0.25, 0.2, -0.5, 0.5, 0.5, 0.5, 0.5, 0.5])


def test_table1_configs_hold_the_paper_protocol():
    spec = load_spec("table1")
    assert (spec.task, spec.algo, spec.sources, spec.seeds) == ("NeedlePick", "ddpgbc", ("script", "novice", "expert"),
                                                                (0, 1, 2, 3))
    assert (spec.episodes, spec.operators, spec.horizon, spec.matched, spec.report_epochs) == (100, 4, 150, True,
                                                                                               (50, 100))
    assert spec.report_episodes == 100   # each report epoch's actor on 100 fresh and 100 probed episodes
    from hydra import compose, initialize_config_dir

    from surrol_data.train_app import config_dir, to_train_config

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = to_train_config(compose("config", overrides=["experiment=table1"]))
    s = cfg.schedule
    assert (s.epochs, s.cycles * s.episodes_per_cycle, s.max_episode_steps) == (100, 40, 150)
    quick = load_spec("table1_quick")
    assert quick.horizon == 150 and quick.episodes % quick.operators == 0
    with pytest.raises(ValueError, match="no `study:` block"):
        load_spec("paper")
    with pytest.raises(ValueError, match="split evenly"):
        dataclasses.replace(spec, episodes=10, operators=4)


@pytest.mark.slow
def test_table1_quick_pipeline_writes_the_report(tmp_path):
    """The one study command on table1_quick (cut to one seed): demo sets, batched training, report files."""
    from typer.testing import CliRunner

    from surrol_data.cli import app
    from surrol_data.datasets.reader import DatasetReader

    out = tmp_path / "table1"
    result = CliRunner().invoke(app, ["study", "table1_quick", "--out", str(out),
                                      "--override", "experiment.study.seeds=[0]"])
    assert result.exit_code == 0, result.output
    for name in ("report.md", "report.html", "learning_curves.png", "demos.md"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    runs = sorted(p.parent.relative_to(out / "runs").as_posix() for p in (out / "runs").rglob("metrics.jsonl"))
    assert runs == ["expert/seed0", "novice/seed0", "script/seed0"]
    human = DatasetReader(out / "demos" / "NeedlePick_human").episodes
    assert sorted(human.groupby(["skill", "operator_id"]).size().items()) == [
        (("expert", "expert1"), 2), (("expert", "expert2"), 2), (("novice", "novice1"), 2), (("novice", "novice2"), 2)]
    assert all('"expert_matched"' in p or '"novice_matched"' in p for p in human["operator_params"])
    script = DatasetReader(out / "demos" / "NeedlePick_script").episodes
    assert len(script) == 4 and all('"oracle_speed": 0.3' in s for s in script["device_settings"])
    report = (out / "report.md").read_text()
    assert "## Table I" in report and "## Demonstrations" in report and "simulated operators" in report
    # rerunning the same command resumes: nothing is recorded or trained twice
    again = CliRunner().invoke(app, ["study", "table1_quick", "--out", str(out),
                                     "--override", "experiment.study.seeds=[0]"])
    assert again.exit_code == 0, again.output
    assert len(DatasetReader(out / "demos" / "NeedlePick_human").episodes) == 8


def test_grasp_events_reach_the_dataset_and_the_metrics(tmp_path):
    """The env's grasp state and drops go from the step info into the recorded frames, so failed grasps and drops
    are counted from a dataset (not nan); a dataset recorded without them still reads, with those counts unknown."""
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.collect.script_source import features_for
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.schema import frame_features

    env = gym.make("SurRoL/NeedlePick-v0", max_episode_steps=60)
    try:
        traj = rollout(env, ORACLE, 5)
        features = features_for(env)
    finally:
        env.close()
    assert traj.flags["grasped"].shape == (len(traj), 1) and traj.flags["grasped"].any()
    assert traj.flags["drop"].shape == (len(traj),)
    prov = {"source": "script", "device": "none", "skill": "scripted", "seed": 5}
    with DatasetRecorder(tmp_path / "events", task="NeedlePick", env_id="SurRoL/NeedlePick-v0", task_description="t",
                         features=features) as rec:
        rec.record(traj, prov)
    back = DatasetReader(tmp_path / "events").trajectory(0)
    np.testing.assert_array_equal(back.flags["grasped"], traj.flags["grasped"])
    np.testing.assert_array_equal(back.flags["drop"], traj.flags["drop"])
    score = trajectory_proficiency(back)
    assert score.failed_grasps == 0.0 and score.drops == 0.0 and score.jaw_closures >= 1

    # a dataset without the event features (recorded before they existed) records and reads as before
    plain = frame_features(obs_dim=19, goal_dim=3, act_dim=5, n_arms=1)
    with DatasetRecorder(tmp_path / "plain", task="NeedlePick", env_id="SurRoL/NeedlePick-v0", task_description="t",
                         features=plain) as rec:
        rec.record(traj, prov)
    old = DatasetReader(tmp_path / "plain").trajectory(0)
    assert "grasped" not in old.flags and np.isnan(trajectory_proficiency(old).failed_grasps)
    # and appending with an env that reports events keeps that dataset's features
    with DatasetRecorder(tmp_path / "plain", task="NeedlePick", env_id="SurRoL/NeedlePick-v0", task_description="t",
                         features=features, append=True) as rec:
        rec.record(traj, {**prov, "seed": 6})
    assert len(DatasetReader(tmp_path / "plain").episodes) == 2

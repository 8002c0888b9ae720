"""Merge, filter (the --where language) and train/valid split, on datasets written by the real recorder.

``make_dataset`` (also used by test_validate and test_export) records real NeedleReach oracle rollouts, so
rewards agree with the task's compute_reward, labelled with varied provenance (sources, operators, skills).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import PROVENANCE_COLUMNS
from surrol_data.datasets.split import split_episodes
from surrol_data.datasets.where import WhereError, compile_where

REPO_ROOT = Path(__file__).resolve().parents[1]
TASK, ENV_ID = "NeedleReach", "SurRoL/NeedleReach-v0"
MAX_STEPS = 15
LABELS = [  # (source, device, skill, operator_id, simulated)
    ("script", "none", "scripted", "oracle", False),
    ("haptic", "touch", "expert", "surgeon1", False),
    ("haptic", "touch", "expert", "surgeon1", False),
    ("haptic", "touch", "novice", "student 2", False),
    ("haptic", "simulated-operator", "novice", "sim-novice-0", True),
    ("script", "none", "scripted", "oracle", False),
]


def rollouts(n: int, first_seed: int = 0):
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401
    from surrol_data.evaluation.rollout import ORACLE, rollout

    env = gym.make(ENV_ID, max_episode_steps=MAX_STEPS)
    try:
        return [rollout(env, ORACLE, first_seed + i) for i in range(n)], env.unwrapped.TASK
    finally:
        env.close()


def make_dataset(root: Path, labels=LABELS, first_seed: int = 0) -> tuple[Path, list]:
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.collect.script_source import features_for

    import gymnasium as gym

    import surrol_data.envs  # noqa: F401

    trajs, description = rollouts(len(labels), first_seed)
    env = gym.make(ENV_ID)
    features = features_for(env)
    env.close()
    with DatasetRecorder(root, features=features, task=TASK, env_id=ENV_ID, task_description=description,
                         command="pytest make_dataset") as rec:
        for i, (traj, (source, device, skill, op, sim)) in enumerate(zip(trajs, labels, strict=True)):
            rec.record(traj, {"source": source, "device": device, "skill": skill, "operator_id": op,
                              "operator_simulated": sim, "seed": first_seed + i, "duration_s": 0.5 + i})
    return root, trajs


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("tools") / "reach")


def assert_same(a, b) -> None:
    for name in ("observation", "achieved_goal", "desired_goal", "action", "reward", "success", "terminated",
                 "tip_position", "jaw_angle"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for flag in ("clutch", "jaw_button"):
        assert np.array_equal(a.flags[flag], b.flags[flag]), flag


# ---------------------------------------------------------------------- --where (no I/O)

ROW = {"episode_index": 3, "length": 15, "source": "haptic", "skill": "expert", "operator_id": "surgeon1",
       "success": True, "operator_simulated": False, "path_length_cm": 12.5, "seed": 7}


@pytest.mark.parametrize("expression, expected", [
    ('skill == "expert" and success', True),
    ('source in {"script", "haptic"}', True),
    ('operator_id in {"student2"}', False),
    ('operator_id not in ["student2"]', True),
    ("not operator_simulated and path_length_cm < 20", True),
    ("10 <= length <= 14", False),
    ('(skill == "novice" or seed > 5) and episode_index != 3', False),
    ("seed >= -1", True),
])
def test_where_language(expression, expected):
    assert compile_where(expression, ROW)(ROW) is expected


@pytest.mark.parametrize("expression, message", [
    ("__import__('os').system('true')", r"Call.*is not allowed"),
    ("skill.upper() == 'X'", r"is not a literal|not allowed"),
    ("colour == 'red'", r"no column 'colour'"),
    ("seed + 1 > 2", r"is not a literal"),
    ("source in operator_id", r"'in' needs a literal set"),
    ("skill ==", r"cannot parse"),
    ("", r"non-empty"),
])
def test_where_rejects_anything_else(expression, message):
    with pytest.raises(WhereError, match=message):
        compile_where(expression, ROW)


def test_split_is_stratified_and_seeded():
    import pandas as pd

    eps = pd.DataFrame({"episode_index": range(40), "source": ["haptic"] * 40,
                        "skill": ["expert"] * 20 + ["novice"] * 20,
                        "operator_id": [f"op{i % 4}" for i in range(40)]})
    train, valid = split_episodes(eps, 0.2, seed=3)
    assert sorted(train + valid) == list(range(40)) and not set(train) & set(valid)
    assert len(valid) == 8
    for (skill, op), rows in eps.groupby(["skill", "operator_id"]):  # every operator in both parts
        ids = set(rows["episode_index"])
        assert ids & set(train) and ids & set(valid), (skill, op)
    assert split_episodes(eps, 0.2, seed=3) == (train, valid)
    assert split_episodes(eps, 0.2, seed=4) != (train, valid)
    with pytest.raises(ValueError, match="between 0 and 1"):
        split_episodes(eps, 1.0)


# ---------------------------------------------------------------------- with datasets


def test_select_with_expression(dataset):
    reader = DatasetReader(dataset[0])
    assert reader.select('skill == "expert"') == [1, 2]
    assert reader.select('source in {"script"} or operator_simulated') == [0, 4, 5]
    assert reader.select('operator_id == "student 2" and length > 0') == [3]
    with pytest.raises(DatasetError, match="no column 'colour'"):
        reader.select('colour == "red"')


def test_merge_keeps_every_provenance_column(dataset, tmp_path):
    from surrol_data.datasets.merge import merge_datasets

    root, trajs = dataset
    other, other_trajs = make_dataset(tmp_path / "other", labels=LABELS[:2], first_seed=20)
    out = merge_datasets(tmp_path / "merged", [root, other], command="surrol-data merge merged a b", progress=False)
    merged = DatasetReader(out)
    assert len(merged) == len(trajs) + 2
    expected = [*DatasetReader(root).episodes.to_dict("records"), *DatasetReader(other).episodes.to_dict("records")]
    got = merged.episodes.to_dict("records")
    for new_index, (a, b) in enumerate(zip(got, expected, strict=True)):
        assert a["episode_index"] == new_index
        for key in PROVENANCE_COLUMNS:  # recorded_at, command, git commit of the original recording included
            assert a[key] == b[key] or (a[key] != a[key] and b[key] != b[key]), key
    for ep, traj in enumerate([*trajs, *other_trajs]):
        assert_same(merged.trajectory(ep), traj)
    side = json.loads((out / "meta" / "surrol_data.json").read_text())
    assert side["derived_from"]["operation"] == "merge"
    assert side["derived_from"]["episodes"][-1] == {"episode": 7, "source_root": str(other), "source_episode": 1}
    assert side["sessions"][-1]["command"] == "surrol-data merge merged a b"
    card = (out / "README.md").read_text()
    assert "## Derived from" in card and "surrol-data merge merged a b" in card and "| expert | surgeon1 | no | 3 |" in card


def test_merge_keeps_an_unknown_duration_unknown_and_valid(dataset, tmp_path):
    """An episode whose wall time was not measured has duration_s NaN; lerobot's aggregation (pandas) made it a null,
    which validate refuses (provenance never holds None): the merged dataset must validate and still say NaN."""
    from surrol_data.datasets.merge import merge_datasets
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.schema import frame_features
    from surrol_data.datasets.validate import validate_dataset

    _, trajs = dataset
    inputs = []
    for name, seeds in (("a", (0, 1)), ("b", (2,))):
        inputs.append(tmp_path / name)
        with DatasetRecorder(inputs[-1], features=frame_features(trajs[0].observation.shape[1], 3, 5, 1), task=TASK,
                             env_id=ENV_ID, task_description="reach", handle_signals=False) as rec:
            for seed in seeds:   # no duration_s: unknown
                rec.record(trajs[seed], {"source": "script", "device": "none", "skill": "scripted", "seed": seed})
    assert np.isnan(DatasetReader(inputs[0]).episodes["duration_s"].astype(float)).all()
    out = merge_datasets(tmp_path / "merged", inputs, progress=False)
    assert validate_dataset(out, check_reward=False) == []
    durations = DatasetReader(out).episodes["duration_s"]
    assert durations.dtype == np.float64 and np.isnan(durations).all()


def test_merge_refuses_incompatible_inputs(dataset, tmp_path):
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.merge import merge_datasets
    from surrol_data.datasets.schema import frame_features

    root, trajs = dataset
    wrong = tmp_path / "pick"
    with DatasetRecorder(wrong, features=frame_features(trajs[0].observation.shape[1], 3, 5, 1), task="NeedlePick",
                         env_id="SurRoL/NeedlePick-v0", task_description="pick") as rec:
        rec.record(trajs[0], {"source": "script", "device": "none", "skill": "scripted", "seed": 0})
    with pytest.raises(DatasetError, match="task='NeedleReach'.*task='NeedlePick'"):
        merge_datasets(tmp_path / "out", [root, wrong], progress=False)
    assert not (tmp_path / "out").exists()
    with pytest.raises(FileExistsError, match="already exists"):
        merge_datasets(root, [root], progress=False)


def test_filter_then_split(dataset, tmp_path):
    from surrol_data.datasets.merge import filter_dataset, split_dataset

    root, trajs = dataset
    out = filter_dataset(root, tmp_path / "haptic", 'source == "haptic" and not operator_simulated', progress=False)
    kept = DatasetReader(out)
    assert list(kept.episodes["operator_id"]) == ["surgeon1", "surgeon1", "student 2"]
    assert list(kept.episodes["seed"]) == [1, 2, 3]
    assert_same(kept.trajectory(2), trajs[3])
    assert json.loads((out / "meta" / "surrol_data.json").read_text())["derived_from"]["where"].startswith("source")
    with pytest.raises(DatasetError, match="no episode selected"):
        filter_dataset(root, tmp_path / "none", 'skill == "guru"', progress=False)

    parts = split_dataset(root, tmp_path / "split", valid_fraction=0.5, seed=1, progress=False)
    train, valid = DatasetReader(parts["train"]), DatasetReader(parts["valid"])
    assert len(train) + len(valid) == len(trajs)
    # (script, scripted, oracle) has 2 episodes and (haptic, expert, surgeon1) 2: one of each goes to valid
    assert sorted(valid.episodes["operator_id"]) == ["oracle", "surgeon1"]
    assert sorted([*train.episodes["seed"], *valid.episodes["seed"]]) == list(range(len(trajs)))
    record = json.loads((tmp_path / "split" / "split.json").read_text())
    assert sorted(record["train"] + record["valid"]) == list(range(len(trajs)))


@pytest.mark.slow  # two CLI processes, each importing lerobot
def test_cli_filter_and_bad_where(dataset, tmp_path):
    root, _ = dataset
    cli = [sys.executable, "-m", "surrol_data.cli"]
    bad = subprocess.run([*cli, "filter", str(root), "--where", "open('x')", "--out", str(tmp_path / "x")],
                         cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "is not allowed" in bad.stdout
    assert not (tmp_path / "x").exists()
    ok = subprocess.run([*cli, "filter", str(root), "--where", 'skill == "expert"', "--out", str(tmp_path / "e")],
                        cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stdout + ok.stderr[-2000:]
    assert DatasetReader(tmp_path / "e").select() == [0, 1]


def test_recorder_checkpoints_without_resume_and_stays_valid(dataset, tmp_path, monkeypatch):
    """The fast checkpoint (close files, continue in new ones) must not fall back to LeRobot's slow resume,
    and what it writes must pass every validate check, LeRobotDataset's own reading included."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.validate import validate_dataset

    root, trajs = dataset
    reader = DatasetReader(root)

    def no_resume(*args, **kwargs):
        raise AssertionError("checkpoint fell back to LeRobotDataset.resume")

    monkeypatch.setattr(LeRobotDataset, "resume", classmethod(no_resume))
    out = tmp_path / "ckpt"
    with DatasetRecorder(out, features={k: v for k, v in reader.features.items()
                                        if k not in ("timestamp", "frame_index", "episode_index", "index",
                                                     "task_index")},
                         task="NeedleReach", env_id="SurRoL/NeedleReach-v0", task_description="reach",
                         checkpoint_every=2, consolidate=False) as rec:   # the files the checkpoints write, as left
        for i, traj in enumerate(trajs[:5]):
            rec.record(traj, {"source": "script", "device": "none", "skill": "scripted", "seed": i})
            assert rec.durable_episodes == 2 * ((i + 1) // 2)
    assert len(list((out / "data").rglob("*.parquet"))) == 3  # episodes 0-1, 2-3, 4
    assert len(list((out / "meta" / "episodes").rglob("*.parquet"))) == 3
    assert validate_dataset(out) == []
    back = DatasetReader(out)
    for ep in range(5):
        assert_same(back.trajectory(ep), trajs[ep])


def _file_digests(root: Path) -> dict[str, str]:
    import hashlib

    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_killed_merge_leaves_no_output_and_its_inputs_untouched(dataset, tmp_path):
    """SIGKILL in the middle of lerobot's aggregation (after the first input's files were copied): no output
    folder, inputs byte for byte as they were, and the next merge into the same folder succeeds and validates."""
    import os
    import signal

    import lerobot.datasets.aggregate as aggregate

    from surrol_data.datasets.merge import merge_datasets, staging_folder
    from surrol_data.datasets.validate import validate_dataset

    root, _ = dataset
    other, _ = make_dataset(tmp_path / "other", labels=LABELS[:2], first_seed=40)
    before = {r: _file_digests(r) for r in (root, other)}
    out = tmp_path / "merged"
    pid = os.fork()
    if pid == 0:  # the merge, killed by itself once lerobot starts on the second input
        try:
            calls = []
            original = aggregate.aggregate_data

            def kill_on_second(*args, **kwargs):
                calls.append(1)
                if len(calls) == 2:
                    os.kill(os.getpid(), signal.SIGKILL)
                return original(*args, **kwargs)

            aggregate.aggregate_data = kill_on_second
            merge_datasets(out, [root, other], progress=False)
        finally:
            os._exit(3)  # not reached when killed
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == -signal.SIGKILL
    assert not out.exists() and staging_folder(out).exists()  # half a merge never carries the output's name
    assert {r: _file_digests(r) for r in (root, other)} == before
    merge_datasets(out, [root, other], progress=False)   # the stale staging folder is cleared
    assert not staging_folder(out).exists()
    assert validate_dataset(out, check_lerobot=False) == []
    assert len(DatasetReader(out)) == len(LABELS) + 2


def test_merge_cli_grammar(dataset, tmp_path):
    from typer.testing import CliRunner

    from surrol_data.cli import app

    root, _ = dataset
    other, _ = make_dataset(tmp_path / "other", labels=LABELS[:1], first_seed=60)
    runner = CliRunner()
    new = runner.invoke(app, ["merge", str(root), str(other), "--out", str(tmp_path / "new")])
    assert new.exit_code == 0, new.output
    old = runner.invoke(app, ["merge", str(tmp_path / "old"), str(root), str(other)])
    assert old.exit_code == 0 and "deprecated" in old.output and len(DatasetReader(tmp_path / "old")) == 7
    missing = runner.invoke(app, ["merge", str(root), str(other)])
    assert missing.exit_code == 2 and "--out OUT" in missing.output
    twice = runner.invoke(app, ["merge", str(root), str(root), "--out", str(tmp_path / "twice")])
    said = " ".join(twice.output.split())
    assert twice.exit_code == 2 and "given more than once" in said and "--drop-duplicates" in said
    assert not (tmp_path / "twice").exists()

"""DatasetReader (pyarrow, no lerobot) and the info summary, on a dataset written by the real recorder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from surrol_data.datasets.info import render_info_text, summarize
from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import PROVENANCE_COLUMNS, frame_features
from surrol_data.datasets.trajectory import Trajectory

REPO_ROOT = Path(__file__).resolve().parents[1]
OBS, GOAL, ARMS = 11, 6, 2
LENGTHS = [6, 9, 4, 12, 7, 5]
PROV = [  # (source, device, skill, operator_id)
    ("script", "none", "scripted", ""),
    ("haptic", "touch", "expert", "surgeon1"),
    ("haptic", "touch", "expert", "surgeon1"),
    ("haptic", "touch", "novice", "student2"),
    ("script", "none", "scripted", ""),
    ("haptic", "simulated-operator", "novice", "sim-novice-0"),
]


def make_traj(seed: int, T: int) -> Trajectory:
    rng = np.random.default_rng(1000 + seed)
    success = np.zeros(T, bool)
    if seed != 3:  # episode 3 never succeeds
        success[rng.integers(0, T):] = True
    return Trajectory(
        observation=rng.standard_normal((T + 1, OBS)).astype(np.float32),
        achieved_goal=rng.standard_normal((T + 1, GOAL)).astype(np.float32),
        desired_goal=rng.standard_normal((T + 1, GOAL)).astype(np.float32),
        action=rng.uniform(-1, 1, (T, 5 * ARMS)).astype(np.float32),
        reward=rng.standard_normal(T).astype(np.float32),
        success=success,
        terminated=rng.random(T) > 0.8,
        tip_position=(0.02 * rng.standard_normal((T + 1, ARMS, 3))).astype(np.float32),
        jaw_angle=rng.uniform(0, 1, (T + 1, ARMS)).astype(np.float32),
        flags={"clutch": rng.random(T) > 0.6, "jaw_button": rng.random(T) > 0.4},
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    from surrol_data.datasets.recorder import DatasetRecorder

    root = tmp_path_factory.mktemp("reader") / "bimanual"
    trajs = [make_traj(i, T) for i, T in enumerate(LENGTHS)]
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5 * ARMS, ARMS), task="NeedleRegrasp",
                         env_id="SurRoL/NeedleRegrasp-v0", task_description="hand the needle over",
                         robot_type="dvrk_psm_bimanual", checkpoint_every=4) as rec:
        for i, (traj, (source, device, skill, op)) in enumerate(zip(trajs, PROV, strict=True)):
            rec.record(traj, {"source": source, "device": device, "skill": skill, "operator_id": op,
                              "operator_simulated": device == "simulated-operator", "seed": i, "duration_s": 1.5})
    return root, trajs


def assert_same(a: Trajectory, b: Trajectory) -> None:
    for name in ("observation", "achieved_goal", "desired_goal", "action", "reward", "success", "terminated",
                 "tip_position", "jaw_angle"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
    for flag in ("clutch", "jaw_button"):
        assert np.array_equal(a.flags[flag], b.flags[flag]), flag


def test_trajectory_is_exactly_what_was_written(dataset):
    root, trajs = dataset
    reader = DatasetReader(root)
    assert len(reader) == len(trajs) and reader.fps == 5
    for ep, traj in enumerate(trajs):
        back = reader.trajectory(ep)
        assert_same(back, traj)  # includes s_T, the last tip position and jaw angle
        assert back.images == {}


def test_trajectories_in_requested_order(dataset):
    root, trajs = dataset
    reader = DatasetReader(root)
    got = reader.trajectories([3, 0, 5])
    for back, ep in zip(got, [3, 0, 5], strict=True):
        assert_same(back, trajs[ep])
    assert len(reader.trajectories()) == len(trajs)


def test_transitions_whole_dataset(dataset):
    root, trajs = dataset
    tr = DatasetReader(root).transitions()
    n = sum(LENGTHS)
    assert tr["obs"].shape == (n, OBS) and tr["obs"].dtype == np.float32
    assert tr["action"].shape == (n, 5 * ARMS) and tr["reward"].shape == (n,)
    assert tr["done"].dtype == bool and tr["success"].dtype == bool and tr["episode_index"].dtype == np.int64
    assert np.array_equal(tr["obs"], np.concatenate([t.observation[:-1] for t in trajs]))
    assert np.array_equal(tr["next_obs"], np.concatenate([t.observation[1:] for t in trajs]))
    assert np.array_equal(tr["next_desired_goal"], np.concatenate([t.desired_goal[1:] for t in trajs]))
    assert np.array_equal(tr["achieved_goal"], np.concatenate([t.achieved_goal[:-1] for t in trajs]))
    assert np.array_equal(tr["reward"], np.concatenate([t.reward for t in trajs]))
    assert np.array_equal(tr["done"], np.concatenate([t.terminated for t in trajs]))
    assert np.array_equal(tr["success"], np.concatenate([t.success for t in trajs]))
    assert np.array_equal(tr["episode_index"], np.repeat(np.arange(len(trajs)), LENGTHS))


def test_transitions_subset_and_empty(dataset):
    root, trajs = dataset
    reader = DatasetReader(root)
    sub = reader.transitions([4, 1])
    assert np.array_equal(sub["episode_index"], np.repeat([1, 4], [LENGTHS[1], LENGTHS[4]]))  # dataset order
    assert np.array_equal(sub["next_obs"][-1], trajs[4].observation[-1])
    empty = reader.transitions([])
    assert empty["obs"].shape == (0, OBS) and empty["reward"].shape == (0,)
    with pytest.raises(DatasetError, match="episode 17 is not in"):
        reader.transitions([17])


def test_episodes_frame_and_select(dataset):
    root, _ = dataset
    reader = DatasetReader(root)
    eps = reader.episodes
    assert list(eps.columns) == ["episode_index", "length", *PROVENANCE_COLUMNS]
    assert list(eps["length"]) == LENGTHS
    assert list(eps["operator_simulated"]) == [False] * 5 + [True]
    assert reader.select() == list(range(6))
    assert reader.select({"skill": "expert"}) == [1, 2]
    assert reader.select({"source": {"script", "haptic"}, "success": True}) == [0, 1, 2, 4, 5]
    assert reader.select({"device": ["touch"], "skill": ("novice",)}) == [3]
    assert reader.select(lambda row: row["length"] > 6 and row["source"] == "haptic") == [1, 3]
    with pytest.raises(DatasetError, match="no column 'colour'.*available"):
        reader.select({"colour": "red"})


def test_clear_errors_for_non_datasets(tmp_path):
    with pytest.raises(DatasetError, match="does not exist: expected a LeRobot v3 dataset folder"):
        DatasetReader(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="meta/info.json is missing"):
        DatasetReader(tmp_path / "empty")
    old = tmp_path / "old" / "meta"
    old.mkdir(parents=True)
    (old / "info.json").write_text(json.dumps({"codebase_version": "v2.1"}))
    with pytest.raises(DatasetError, match="'v2.1'.*expected 'v3.0'"):
        DatasetReader(tmp_path / "old")


def test_summary_numbers(dataset):
    root, trajs = dataset
    s = summarize(root)
    assert (s["episodes"], s["frames"], s["fps"]) == (6, sum(LENGTHS), 5)
    assert s["tasks"] == ["NeedleRegrasp"] and s["robot_type"] == "dvrk_psm_bimanual"
    assert s["sidecar"]["env_id"] == "SurRoL/NeedleRegrasp-v0"
    assert s["features"]["action"] == {"dtype": "float32", "shape": [10]}
    groups = {(g["source"], g["device"], g["skill"], g["operator_id"]): g for g in s["groups"]}
    assert {k: g["episodes"] for k, g in groups.items()} == {
        ("haptic", "simulated-operator", "novice", "sim-novice-0"): 1, ("haptic", "touch", "expert", "surgeon1"): 2,
        ("haptic", "touch", "novice", "student2"): 1, ("script", "none", "scripted", ""): 2}
    prof = [trajectory_proficiency(t) for t in trajs]
    expert = groups[("haptic", "touch", "expert", "surgeon1")]
    assert expert["frames"] == LENGTHS[1] + LENGTHS[2] and expert["success_rate"] == 1.0
    assert expert["mean_path_length_cm"] == pytest.approx(np.mean([prof[1].path_length_cm, prof[2].path_length_cm]))
    assert expert["mean_steps_to_success"] == pytest.approx(np.mean([prof[1].steps_to_success,
                                                                     prof[2].steps_to_success]))
    assert expert["mean_jaw_closures"] == pytest.approx(np.mean([prof[1].jaw_closures, prof[2].jaw_closures]))
    novice = groups[("haptic", "touch", "novice", "student2")]
    assert novice["success_rate"] == 0.0 and np.isnan(novice["mean_steps_to_success"])
    assert s["overall"]["success_rate"] == pytest.approx(5 / 6)

    text = render_info_text(root)
    assert "NeedleRegrasp" in text and "surgeon1" in text and "sim-novice-0" in text
    assert "83.3 %" in text  # overall success rate


def test_reader_and_info_do_not_import_lerobot(dataset):
    root, _ = dataset
    code = ("import sys; from surrol_data.datasets.reader import DatasetReader; "
            "from surrol_data.datasets.info import summarize; "
            f"r = DatasetReader({str(root)!r}); r.transitions(); r.trajectory(0); summarize({str(root)!r}); "
            "assert 'lerobot' not in sys.modules and 'torch' not in sys.modules, 'heavy import'")
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr[-2000:]

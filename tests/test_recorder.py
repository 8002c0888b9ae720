"""DatasetRecorder with the real lerobot: write, reload, provenance, append, signals, SIGKILL + repair."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from surrol_data.datasets.metrics import trajectory_proficiency
from surrol_data.datasets.reader import DatasetError, DatasetReader, unreadable_parquet_files
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.datasets.repair import repair
from surrol_data.datasets.schema import (
    PROVENANCE_COLUMNS,
    SCHEMA_VERSION,
    ProvenanceError,
    frame_features,
    normalize_provenance,
)
from surrol_data.datasets.trajectory import Trajectory

REPO_ROOT = Path(__file__).resolve().parents[1]
OBS, GOAL = 7, 3
RECORDER_ARGS = dict(task="NeedlePick", env_id="SurRoL/NeedlePick-v0", task_description="pick up the needle")


def make_traj(seed: int, T: int, n_arms: int = 1, cameras: dict | None = None) -> Trajectory:
    rng = np.random.default_rng(seed)
    success = np.zeros(T, bool)
    if seed % 3:
        success[T // 2:] = True
    return Trajectory(
        observation=rng.standard_normal((T + 1, OBS)).astype(np.float32),
        achieved_goal=rng.standard_normal((T + 1, GOAL)).astype(np.float32),
        desired_goal=rng.standard_normal((T + 1, GOAL)).astype(np.float32),
        action=rng.uniform(-1, 1, (T, 5 * n_arms)).astype(np.float32),
        reward=(success.astype(np.float32) - 1.0),
        success=success,
        terminated=np.arange(T) == T - 1 if seed % 2 else np.zeros(T, bool),
        tip_position=(0.01 * rng.standard_normal((T + 1, n_arms, 3))).astype(np.float32),
        jaw_angle=rng.uniform(0, 1, (T + 1, n_arms)).astype(np.float32),
        flags={"clutch": rng.random(T) > 0.7, "jaw_button": rng.random(T) > 0.5},
        images={c: rng.integers(0, 255, (T + 1, h, w, 3), dtype=np.uint8) for c, (h, w) in (cameras or {}).items()},
    )


def provenance(i: int) -> dict:
    return {"source": "script" if i % 2 == 0 else "haptic", "device": "none" if i % 2 == 0 else "touch",
            "skill": "expert" if i % 3 == 0 else "novice", "seed": 100 + i, "operator_id": f"op{i % 2}",
            "device_settings": {"scaling": [0.4, 0.4, 0.4]}}


def record_small_dataset(root: Path, episodes: int, steps: int = 6) -> Path:
    """A state-only dataset of ``episodes`` synthetic episodes of ``steps`` frames, written by the real recorder."""
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), **RECORDER_ARGS) as rec:
        for i in range(episodes):
            rec.record(make_traj(i, steps), provenance(i))
    return root


def assert_same(a: Trajectory, b: Trajectory) -> None:
    for name in ("observation", "achieved_goal", "desired_goal", "action", "reward", "success", "terminated",
                 "tip_position", "jaw_angle"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y), name
    for flag in ("clutch", "jaw_button"):
        assert np.array_equal(a.flags[flag], b.flags[flag]), flag


@pytest.fixture(scope="session")
def LeRobotDataset():
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset


@pytest.fixture(scope="module")
def written(tmp_path_factory, LeRobotDataset):
    root = tmp_path_factory.mktemp("rec") / "needle"
    trajs = [make_traj(i, 8 + i) for i in range(5)]
    # one file per checkpoint (not consolidated): the layout a killed recording leaves, which repair works on
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=2, consolidate=False,
                         **RECORDER_ARGS) as rec:
        indices = [rec.record(t, provenance(i)) for i, t in enumerate(trajs)]
    return root, trajs, indices


# ---------------------------------------------------------------------- schema (no lerobot)


def test_frame_features_shapes_and_names():
    f = frame_features(obs_dim=19, goal_dim=3, act_dim=10, n_arms=2, cameras={"front": (64, 48)})
    assert f["observation.state"]["shape"] == (19,)
    assert f["action"]["names"][:5] == ["psm1_dx", "psm1_dy", "psm1_dz", "psm1_dyaw", "psm1_jaw"]
    assert f["complementary_info.tip_position"]["shape"] == (6,)
    assert f["complementary_info.jaw_angle"]["names"] == ["psm1_jaw", "psm2_jaw"]
    assert f["next.done"] == {"dtype": "bool", "shape": (1,), "names": ["done"]}
    assert f["next.truncated"] == {"dtype": "bool", "shape": (1,), "names": ["truncated"]}
    assert f["observation.environment_state"]["names"] == ["achieved_x", "achieved_y", "achieved_z",
                                                           "goal_x", "goal_y", "goal_z"]
    assert not any(k.endswith("_goal") for k in f)  # the goals are the halves of the environment state
    assert all(len(ft["names"]) == ft["shape"][0] for k, ft in f.items() if ft["dtype"] != "video")
    assert f["observation.images.front"]["shape"] == (64, 48, 3)
    assert not any(k.startswith("observation.") and "tip" in k for k in f)  # bookkeeping is not a policy input
    with pytest.raises(ValueError, match="obs_dim"):
        frame_features(0, 3, 5, 1)


def test_normalize_provenance_fills_metrics_and_defaults():
    traj = make_traj(1, 12)
    prov = normalize_provenance({"source": "haptic", "device": "touch", "skill": "expert", "seed": np.int64(3),
                                 "task": "NeedlePick", "env_id": "e", "operator_params": {"gain": np.float32(2)}},
                                traj)
    assert list(prov) == list(PROVENANCE_COLUMNS)
    assert all(type(prov[k]) is t for k, t in PROVENANCE_COLUMNS.items())
    p = trajectory_proficiency(traj)
    assert (prov["success"], prov["steps_to_success"], prov["episode_steps"]) == (p.success, p.steps_to_success, 12)
    assert prov["path_length_cm"] == pytest.approx(p.path_length_cm)
    assert json.loads(prov["operator_params"]) == {"gain": 2.0}
    assert prov["recorded_at"].endswith("Z") and prov["git_commit"] == "" and np.isnan(prov["duration_s"])


@pytest.mark.parametrize("change, message", [
    ({"seed": None}, r"provenance\['seed'\] = None .*expected int.*never None"),
    ({"seed": 1.5}, r"provenance\['seed'\].*expected int"),
    ({"skill": "guru"}, r"provenance\['skill'\] = 'guru': expected one of"),
    ({"operator_simulated": 1}, r"provenance\['operator_simulated'\].*expected bool"),
    ({"colour": "red"}, r"unknown provenance key\(s\) \['colour'\]"),
    ({"device_settings": "{not json"}, r"device_settings.*JSON"),
])
def test_normalize_provenance_errors_name_the_key(change, message):
    base = {"source": "script", "device": "none", "skill": "scripted", "seed": 0, "task": "t", "env_id": "e"}
    with pytest.raises(ProvenanceError, match=message):
        normalize_provenance({**base, **change}, make_traj(0, 5))


def test_normalize_provenance_requires_core_keys():
    with pytest.raises(ProvenanceError, match=r"lacks required key\(s\) \['skill', 'seed'\]"):
        normalize_provenance({"source": "script", "device": "none", "task": "t", "env_id": "e"}, make_traj(0, 5))


# ---------------------------------------------------------------------- with lerobot


def test_write_then_lerobot_loads_offline(written, LeRobotDataset):
    root, trajs, indices = written
    assert indices == list(range(5))
    ds = LeRobotDataset("local/needle", root=root, video_backend="pyav")
    assert ds.num_episodes == 5 and ds.num_frames == sum(len(t) for t in trajs)
    assert ds.fps == 5 and ds.meta.robot_type == "dvrk_psm"
    ep = ds.meta.episodes
    assert list(ep["provenance/skill"]) == [provenance(i)["skill"] for i in range(5)]
    assert list(ep["provenance/seed"]) == [100 + i for i in range(5)]
    assert list(ep["provenance/episode_steps"]) == [len(t) for t in trajs]
    assert all(f"provenance/{k}" in ep.column_names for k in PROVENANCE_COLUMNS)
    item = ds[0]
    assert np.array_equal(item["observation.state"].numpy(), trajs[0].observation[0])
    assert np.array_equal(item["next.observation.state"].numpy(), trajs[0].observation[1])
    assert item["task"] == "pick up the needle"
    last = ds[len(trajs[0]) - 1]  # last frame of episode 0 carries s_T
    assert np.array_equal(last["next.observation.state"].numpy(), trajs[0].observation[-1])
    # object and goal state where LeRobot policies look for it; truncation marked on the last frame only
    assert np.array_equal(item["observation.environment_state"].numpy(),
                          np.concatenate([trajs[0].achieved_goal[0], trajs[0].desired_goal[0]]))
    assert not bool(item["next.truncated"]) and bool(last["next.truncated"]) != bool(trajs[0].terminated[-1])

    experts = LeRobotDataset("local/needle", root=root, video_backend="pyav",
                             episode_filter=lambda e: e["provenance/skill"] == "expert")
    assert experts.episodes == [0, 3]
    assert len(experts) == len(trajs[0]) + len(trajs[3])


def test_sidecar_and_card(written):
    root, trajs, _ = written
    side = json.loads((root / "meta" / "surrol_data.json").read_text())
    assert side["schema_version"] == SCHEMA_VERSION == 2 and side["env_id"] == "SurRoL/NeedlePick-v0" and side["fps"] == 5
    assert side["sessions"][-1]["episodes"] == 5 and side["checkpoint"]["episodes"] == 5
    card = (root / "README.md").read_text()
    from huggingface_hub import DatasetCard

    data = DatasetCard(card).data        # huggingface_hub parses the front matter
    assert data.task_categories == ["robotics"] and "LeRobot" in data.tags and data.size_categories == ["n<1K"]
    assert str(root) not in card and str(root.parent) not in card   # no path of the recording machine
    assert "data_files: data/*/*.parquet" in card and "NeedlePick" in card
    assert "| script | none | 3 |" in card and "| haptic | touch | 2 |" in card


def test_append_resumes_and_checks(written, LeRobotDataset, tmp_path):
    import shutil

    root = tmp_path / "needle"
    shutil.copytree(written[0], root)
    with pytest.raises(FileExistsError, match="--append"):
        DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), **RECORDER_ARGS)
    with pytest.raises(ValueError, match="observation.state: given float32\\(9,\\), dataset has float32\\(7,\\)"):
        DatasetRecorder(root, features=frame_features(9, GOAL, 5, 1), append=True, **RECORDER_ARGS)
    with pytest.raises(ValueError, match="env_id='SurRoL/NeedlePick-v0'"):
        DatasetRecorder(root, append=True, **{**RECORDER_ARGS, "env_id": "SurRoL/GauzeRetrieve-v0"})

    new = [make_traj(50 + i, 6) for i in range(3)]
    with DatasetRecorder(root, append=True, checkpoint_every=2, **RECORDER_ARGS) as rec:
        assert rec.num_episodes == 5
        got = [rec.record(t, {**provenance(i), "skill": "expert"}) for i, t in enumerate(new)]
    assert got == [5, 6, 7]
    ds = LeRobotDataset("local/needle", root=root, video_backend="pyav",
                        episode_filter=lambda e: e["provenance/skill"] == "expert")
    assert ds.episodes == [0, 3, 5, 6, 7]
    assert ds.meta.total_episodes == 8
    reader = DatasetReader(root)
    for i, t in enumerate(new):
        assert_same(reader.trajectory(5 + i), t)
    assert len(json.loads((root / "meta" / "surrol_data.json").read_text())["sessions"]) == 2


def test_bad_trajectory_is_rejected_without_damage(tmp_path, LeRobotDataset):
    root = tmp_path / "ds"
    with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), **RECORDER_ARGS) as rec:
        rec.record(make_traj(0, 5), provenance(0))
        bad = make_traj(1, 5)
        bad.observation = bad.observation[:, :4]
        with pytest.raises(ValueError, match=r"Trajectory.observation has shape \(6, 4\), the dataset expects \(6, 7\)"):
            rec.record(bad, provenance(1))
        with pytest.raises(ValueError, match="images has cameras \\['wrist'\\]"):
            rec.record(make_traj(2, 5, cameras={"wrist": (8, 8)}), provenance(2))
        with pytest.raises(ProvenanceError, match="skill"):
            rec.record(make_traj(3, 5), {**provenance(3), "skill": None})
        assert rec.record(make_traj(4, 5), provenance(4)) == 1
    assert LeRobotDataset("local/ds", root=root, video_backend="pyav").num_episodes == 2


def test_exception_mid_session_finalizes(tmp_path, LeRobotDataset):
    root = tmp_path / "ds"
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(RuntimeError, match="boom"):
        with DatasetRecorder(root, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every=100,
                             **RECORDER_ARGS) as rec:
            for i in range(3):
                rec.record(make_traj(i, 7), provenance(i))
            assert signal.getsignal(signal.SIGTERM) != previous
            raise RuntimeError("boom")
    assert signal.getsignal(signal.SIGTERM) == previous  # handlers restored
    assert not unreadable_parquet_files(root)
    ds = LeRobotDataset("local/ds", root=root, video_backend="pyav")
    assert ds.num_episodes == 3 and len(ds.meta.episodes) == 3


def test_video_camera_round_trip(tmp_path, LeRobotDataset):
    root = tmp_path / "cam"
    features = frame_features(OBS, GOAL, 5, 1, cameras={"front": (64, 64)})
    trajs = [make_traj(i, 4, cameras={"front": (64, 64)}) for i in range(2)]
    with DatasetRecorder(root, features=features, **RECORDER_ARGS) as rec:
        for i, t in enumerate(trajs):
            rec.record(t, provenance(i))
    ds = LeRobotDataset("local/cam", root=root, video_backend="pyav")
    assert ds.num_frames == 8
    img = ds[5]["observation.images.front"]
    assert tuple(img.shape) == (3, 64, 64)
    assert_same(DatasetReader(root).trajectory(1), trajs[1])  # reader skips the video, keeps the rest


# ---------------------------------------------------------------------- signals (subprocess)

CHILD = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from test_recorder import make_traj, provenance, RECORDER_ARGS, OBS, GOAL
    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.schema import frame_features

    with DatasetRecorder({root!r}, features=frame_features(OBS, GOAL, 5, 1), checkpoint_every={every},
                         checkpoint_interval_s=None, **RECORDER_ARGS) as rec:
        print("open", flush=True)
        i = 0
        while True:
            traj = make_traj(i, 10)
            time.sleep(0.05)  # 'collecting' the next episode: where a signal usually lands
            rec.record(traj, provenance(i))
            print("done", i, rec.durable_episodes, flush=True)
            i += 1
""")


def _run_child(tmp_path: Path, every: int, until_done: int) -> tuple[subprocess.Popen, list[tuple[int, int]]]:
    root = tmp_path / "live"
    script = tmp_path / "child.py"
    script.write_text(CHILD.format(tests=str(Path(__file__).parent), root=str(root), every=every))
    proc = subprocess.Popen([sys.executable, str(script)], cwd=REPO_ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    done: list[tuple[int, int]] = []
    deadline = time.monotonic() + 60
    while len(done) < until_done:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError(f"child ended early (rc={proc.wait()}): {proc.stderr.read()[-2000:]}")
        if line.startswith("done"):
            _, ep, durable = line.split()
            done.append((int(ep), int(durable)))
        assert time.monotonic() < deadline, "child too slow"
    return proc, done


def test_sigterm_mid_session_keeps_every_completed_episode(tmp_path, LeRobotDataset):
    proc, done = _run_child(tmp_path, every=100, until_done=3)
    time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err[-2000:]
    completed = len(done) + out.count("done")
    root = tmp_path / "live"
    assert not unreadable_parquet_files(root)
    ds = LeRobotDataset("local/live", root=root, video_backend="pyav")
    # an episode can complete between the last line we read and the signal: it must be there too
    assert completed <= ds.num_episodes <= completed + 1
    reader = DatasetReader(root)
    for ep in range(ds.num_episodes):
        assert_same(reader.trajectory(ep), make_traj(ep, 10))


def test_sigkill_then_repair_keeps_every_finished_episode(tmp_path, LeRobotDataset):
    """Checkpoints every 100 episodes: every finished one survives a SIGKILL through the journal."""
    proc, done = _run_child(tmp_path, every=100, until_done=5)
    proc.kill()
    proc.communicate(timeout=30)
    root = tmp_path / "live"
    finished = len(done)

    if unreadable_parquet_files(root):
        with pytest.raises(DatasetError, match="repair"):
            DatasetReader(root)
    report = repair(root)
    kept = report["episodes_kept"]
    assert finished <= kept <= finished + 1  # the episode in progress may have finished after our last read
    assert not unreadable_parquet_files(root)
    ds = LeRobotDataset("local/live", root=root, video_backend="pyav")
    assert ds.num_episodes == kept and ds.num_frames == 10 * kept
    reader = DatasetReader(root)
    assert len(reader) == kept
    for ep in range(kept):
        assert_same(reader.trajectory(ep), make_traj(ep, 10))
    assert repair(root)["backup_dir"] is None  # idempotent: nothing left to fix

    with DatasetRecorder(root, append=True, **RECORDER_ARGS) as rec:
        assert rec.record(make_traj(kept, 10), provenance(kept)) == kept
    ds = LeRobotDataset("local/live", root=root, video_backend="pyav")
    assert ds.num_episodes == kept + 1
    assert list(ds.meta.episodes["provenance/seed"]) == [100 + i for i in range(kept + 1)]


def test_repair_drops_episodes_whose_frames_are_lost(written, LeRobotDataset, tmp_path):
    """A data file cut short (no footer) while later metadata survived; info.json cut short too."""
    import shutil

    root = tmp_path / "needle"
    shutil.copytree(written[0], root)
    trajs = written[1]
    data_files = sorted((root / "data").rglob("*.parquet"))
    assert len(data_files) == 3  # checkpoint_every=2 over 5 episodes: 0-1, 2-3, 4
    raw = data_files[1].read_bytes()
    data_files[1].write_bytes(raw[: len(raw) // 2])
    info = (root / "meta" / "info.json").read_text()
    (root / "meta" / "info.json").write_text(info[:40])

    with pytest.raises(DatasetError, match="repair"):
        DatasetReader(root)
    report = repair(root)
    # episodes 2-3 lived in the damaged file; episode 4, after it, is salvaged and renumbered
    assert (report.episodes_kept, report.episodes_salvaged) == (3, 1)
    assert [ep for ep, _ in report.dropped] == [2, 3]
    assert all("file-001.parquet, which is unreadable" in why for _, why in report.dropped)
    assert "data/chunk-000/file-001.parquet" in report.moved
    assert Path(report.backup_dir, "data/chunk-000/file-001.parquet").exists()  # moved aside, not deleted
    ds = LeRobotDataset("local/needle", root=root, video_backend="pyav")
    assert ds.num_episodes == 3 and ds.num_frames == len(trajs[0]) + len(trajs[1]) + len(trajs[4])
    stats = json.loads((root / "meta" / "stats.json").read_text())
    assert stats["action"]["count"] == [ds.num_frames]  # re-aggregated over the kept episodes only
    reader = DatasetReader(root)
    assert_same(reader.trajectory(1), trajs[1])
    assert_same(reader.trajectory(2), trajs[4])
    assert list(reader.episodes["seed"]) == [100, 101, 104]  # provenance travels with the salvaged episode
    assert json.loads((root / "meta" / "surrol_data.json").read_text())["repairs"][-1]["episodes_kept"] == 3


def test_repair_refuses_a_non_dataset(tmp_path):
    with pytest.raises(DatasetError, match="not a LeRobot dataset"):
        repair(tmp_path)

"""Exports read back by the target libraries' own readers: robomimic's SequenceDataset and minari.load_dataset."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_dataset_tools import LABELS, make_dataset

from surrol_data.datasets.reader import DatasetReader

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("export") / "reach")


def test_robomimic_sequence_dataset_reads_the_export(dataset, tmp_path):
    import h5py
    import robomimic.utils.obs_utils as ObsUtils
    from robomimic.utils.dataset import SequenceDataset

    from surrol_data.datasets.export_robomimic import OBS_KEYS, export_robomimic

    root, trajs = dataset
    path = export_robomimic(root, tmp_path / "reach.hdf5", valid_fraction=0.5, seed=0, progress=False)
    ObsUtils.initialize_obs_utils_with_obs_specs({"obs": {"low_dim": list(OBS_KEYS)}})

    full = SequenceDataset(hdf5_path=str(path), obs_keys=OBS_KEYS, dataset_keys=("actions", "rewards", "dones"),
                           load_next_obs=True, hdf5_cache_mode=None, hdf5_use_swmr=False)
    assert full.n_demos == len(trajs) and len(full) == sum(len(t) for t in trajs)
    start = 0
    for i, traj in enumerate(trajs):  # every sample of every demo is the recorded transition
        for t in (0, len(traj) - 1):
            item = full[start + t]
            assert np.array_equal(item["obs"]["observation"][0], traj.observation[t])
            assert np.array_equal(item["next_obs"]["desired_goal"][0], traj.desired_goal[t + 1])
            assert np.array_equal(item["actions"][0], traj.action[t])
            assert item["rewards"][0] == traj.reward[t]
        assert full[start + len(traj) - 1]["dones"][0] == 1
        start += len(traj)
    full.close_and_delete_hdf5_handle()

    experts = SequenceDataset(hdf5_path=str(path), obs_keys=OBS_KEYS, dataset_keys=("actions",),
                              filter_by_attribute="skill_expert", hdf5_cache_mode=None, hdf5_use_swmr=False)
    assert sorted(experts.demos) == ["demo_1", "demo_2"]
    experts.close_and_delete_hdf5_handle()

    with h5py.File(path, "r") as f:
        env_args = json.loads(f["data"].attrs["env_args"])
        assert env_args == {"env_name": "SurRoL/NeedleReach-v0", "type": 2, "env_kwargs": {}}
        assert f["data"].attrs["total"] == sum(len(t) for t in trajs)
        masks = {k: sorted(v.decode() for v in f["mask"][k][:]) for k in f["mask"]}
        demo = f["data/demo_3"]
        assert demo.attrs["operator_id"] == "student 2" and demo.attrs["skill"] == "novice"
        assert demo.attrs["num_samples"] == len(trajs[3]) and demo["states"].shape == (len(trajs[3]), 7)
    assert masks["operator_student_2"] == ["demo_3"] and masks["source_script"] == ["demo_0", "demo_5"]
    assert sorted(masks["train"] + masks["valid"]) == sorted(f"demo_{i}" for i in range(len(trajs)))
    assert not set(masks["train"]) & set(masks["valid"])
    assert sorted(masks["skill_expert_train"] + masks["skill_expert_valid"]) == ["demo_1", "demo_2"]
    with pytest.raises(FileExistsError, match="--overwrite"):
        export_robomimic(root, path, progress=False)


def test_minari_load_dataset_reads_the_export(dataset, tmp_path, monkeypatch):
    import minari

    from surrol_data.datasets.export_minari import export_minari

    root, trajs = dataset
    out = tmp_path / "minari"
    export_minari(root, out, dataset_id="surrol/NeedleReach/experts-v0", where='skill == "expert"', progress=False)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    assert (out / "surrol" / "NeedleReach" / "experts-v0" / "data" / "main_data.hdf5").exists()
    ds = minari.load_dataset("surrol/NeedleReach/experts-v0")
    assert ds.total_episodes == 2 and ds.total_steps == len(trajs[1]) + len(trajs[2])
    for episode, source in zip(ds.iterate_episodes(), (1, 2), strict=True):
        traj = trajs[source]
        assert np.array_equal(episode.observations["observation"], traj.observation)  # N+1, reset included
        assert np.array_equal(episode.observations["desired_goal"], traj.desired_goal)
        assert np.array_equal(episode.actions, traj.action)
        assert np.allclose(episode.rewards, traj.reward)
        assert np.array_equal(episode.terminations, traj.terminated)
        assert episode.truncations[-1] and not episode.truncations[:-1].any()
        assert np.array_equal(episode.infos["is_success"][1:], traj.success)
    meta = list(ds.storage.get_episode_metadata([0, 1]))
    assert [m["operator_id"] for m in meta] == ["surgeon1", "surgeon1"] and [m["seed"] for m in meta] == [1, 2]
    assert ds.spec.action_space.shape == (5,) and ds.spec.observation_space["observation"].shape == (7,)
    assert os.environ["MINARI_DATASETS_PATH"] == str(out)  # the export restored, not leaked, its own setting
    with pytest.raises(FileExistsError, match="already exists"):
        export_minari(root, out, dataset_id="surrol/NeedleReach/experts-v0", progress=False)


def test_push_dry_run_lists_files_without_network(dataset, tmp_path):
    from surrol_data.datasets.push import plan_push, push_dataset

    root, _ = dataset
    (root / "images").mkdir(exist_ok=True)
    (root / "images" / "frame-000000.png").write_bytes(b"staging")
    plan = push_dataset(root, "lab/needle-reach", dry_run=True)
    assert "README.md" in plan.files and "meta/info.json" in plan.files and "meta/surrol_data.json" in plan.files
    assert any(f.startswith("data/chunk-000/") for f in plan.files)
    assert not any(f.startswith("images/") for f in plan.files)
    assert plan.revision_tag == "v3.0" and plan.bytes > 0
    with pytest.raises(ValueError, match="user_or_org/name"):
        plan_push(root, "no-slash")
    cli = subprocess.run([sys.executable, "-m", "surrol_data.cli", "push", str(root), "--repo-id", "lab/x", "--dry-run"],
                         cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert cli.returncode == 0 and "would upload" in cli.stdout and "meta/info.json" in cli.stdout


def test_dataset_card_front_matter(dataset):
    root, trajs = dataset
    card = (root / "README.md").read_text()
    header = card.split("---\n")[1]
    for line in ("license: apache-2.0", "- robotics", "- NeedleReach", "- config_name: default",
                 "data_files: data/*/*.parquet", "- n<1K"):
        assert line in header, line
    s = DatasetReader(root).episodes
    assert f"{len(trajs)} episodes, {int(s['length'].sum())} frames" in card
    assert "| haptic | touch | 3 |" in card and "| novice | sim-novice-0 | yes | 1 |" in card
    assert "## Proficiency" in card and "pytest make_dataset" in card  # the command line that made it
    assert len(LABELS) == len(trajs)


def test_card_keeps_only_relative_paths():
    from surrol_data.datasets.card import relative_command

    assert relative_command("surrol-data collect --out /home/me/data/NP_script --episodes 5") == \
        "surrol-data collect --out NP_script --episodes 5"
    assert relative_command("surrol-data merge --out=/abs/merged a b") == "surrol-data merge --out=merged a b"
    assert relative_command("unbalanced 'quote") == "unbalanced 'quote"


@pytest.mark.parametrize("hdf5_reports", ["the disk's error", "a RuntimeError"])
def test_a_write_that_fails_inside_hdf5_is_the_disks_error_and_leaves_no_file(dataset, tmp_path, monkeypatch,
                                                                               hdf5_reports):
    """A disk that fills while HDF5 writes the file out on closing it: the export raises the disk's own error (the
    CLI's one-line message) and removes its partial file, whether HDF5 passes the write's OSError on or turns it into
    a RuntimeError that names no cause, "driver write request failed", as the fault sweep met it
    (benchmarks/crash_safety.py --faults --fault-paths export)."""
    import errno

    import surrol_data.datasets.export_robomimic as export

    import h5py

    closing = {"now": False}
    real_write, real_close = export._WritesThrough.write, h5py.File.close

    def write(self, data):   # the disk fills as HDF5 writes out what it held back, on closing the file
        if closing["now"]:
            return self._kept(lambda _: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")), data)
        return real_write(self, data)

    def close(self):
        closing["now"] = True
        try:
            return real_close(self)
        except OSError:
            if hdf5_reports == "the disk's error":
                raise
            raise RuntimeError("Can't close file (file write failed: driver write request failed)") from None

    monkeypatch.setattr(export._WritesThrough, "write", write)
    monkeypatch.setattr(h5py.File, "close", close)
    out = tmp_path / "full.hdf5"
    with pytest.raises(OSError) as raised:
        export.export_robomimic(dataset[0], out, progress=False)
    assert raised.value.errno == errno.ENOSPC
    assert not out.exists() and not out.with_name(out.name + ".partial").exists()

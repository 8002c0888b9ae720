"""Export a dataset to one robomimic HDF5 file (robomimic's v0.1 layout, read by robomimic >= 0.3).

Layout (shared/docs/reference/algorithms.md §6.1)::

    data                attrs total (samples), env_args (JSON: env_name = gym id, type = 2 (gym), env_kwargs)
    data/demo_<i>       attrs num_samples, plus the episode's provenance (source, operator_id, skill, seed, ...)
        obs/<key>       (N, dim) float32 for key in observation, achieved_goal, desired_goal: s_0..s_{N-1}
        obs/<camera>_image  (N, H, W, 3) uint8 for each camera of the dataset (e.g. endoscope_image)
        next_obs/<key>  (N, dim): s_1..s_N
        actions (N, A), rewards (N,), dones (N,) (1 where the env terminated, and at the last step)
        states (N, obs_dim): the observation vector (robomimic wants one; SurRoL has no MuJoCo state)
        is_intervention (N,) float32, intervention_arms (N, n_arms) uint8, policy_actions (N, A): who acted and
            what the policy proposed, for episodes of an intervention session (``collect --source intervene``)
    mask/<key>          byte strings of demo names — filter keys:
        train, valid                       (stratified split, see surrol_data.datasets.split)
        skill_<skill>, operator_<id>, source_<source>, successful
        and <key>_train / <key>_valid for each of those (robomimic's convention for subset + validation)

Train on a subset with robomimic's ``config.train.hdf5_filter_key = "skill_expert"``. Demo ``demo_i`` is the
i-th exported episode; its source episode index is the demo attr ``episode_index``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from tqdm import tqdm

from surrol_data.datasets.episode_ranges import chosen_episodes
from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import PROVENANCE_COLUMNS
from surrol_data.datasets.split import split_episodes
from surrol_data.datasets.trajectory import INTERVENTION

GYM_ENV_TYPE = 2  # robomimic.envs.env_base.EnvType.GYM_TYPE
OBS_KEYS = ("observation", "achieved_goal", "desired_goal")


def mask_name(prefix: str, value: str) -> str:
    """A filter-key name robomimic and HDF5 accept: ``operator_surgeon-1`` -> ``operator_surgeon-1``."""
    clean = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(value)).strip("_") or "unknown"
    return f"{prefix}_{clean}"


def export_robomimic(src: str | Path, out: str | Path, *, where: str | None = None, valid_fraction: float = 0.1,
                     seed: int = 0, overwrite: bool = False, progress: bool = True,
                     episodes: list[int] | None = None) -> Path:
    """Write the episodes of ``src`` (those matching ``where`` and listed in ``episodes``, default all) to the
    robomimic file ``out``; camera frames go to ``obs/<camera>_image``."""
    from surrol_data.extras import require

    h5py = require("h5py")

    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists: pass --overwrite or choose another file")
    if out.suffix not in (".hdf5", ".h5"):
        raise ValueError(f"{out}: a robomimic dataset is one .hdf5 file; name it e.g. demos.hdf5")
    from surrol_data.datasets.guard import require_valid

    # cheap checks: a damaged dataset is refused before anything is written (read: a read-only one's repaired view)
    reader = DatasetReader(require_valid(src))
    episodes = chosen_episodes(reader, where, episodes)
    if not episodes:
        raise DatasetError(f"no episode of {src} to export" + (f" matches --where {where!r}" if where else ""))
    cameras = reader.cameras
    rows = reader.episodes.set_index("episode_index")
    side = read_sidecar(src)
    env_id = side.get("env_id") or str(rows["env_id"].iloc[0])
    chosen = reader.episodes[reader.episodes["episode_index"].isin(episodes)]
    train, valid = split_episodes(chosen, valid_fraction, seed) if len(episodes) > 1 else (episodes, [])
    is_train = set(train)

    masks: dict[str, list[str]] = {"train": [], "valid": []}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    total = 0
    # HDF5 is given a Python file to write through: its own (C) writes meet a full disk with errors it can only print
    # ("Exception ignored in ObjectID.__dealloc__") and then a segmentation fault; through Python the failed write
    # is the OSError it is, and the half-written file is removed
    fh = None
    try:
        with open(tmp, "w+b") as raw, h5py.File(fh := _WritesThrough(raw), "w") as f:
            data = f.create_group("data")
            for i, ep in enumerate(tqdm(episodes, desc=f"export robomimic {out.name}", unit="ep",
                                        disable=not progress)):
                traj = reader.trajectory(ep, images=bool(cameras))
                name = f"demo_{i}"
                demo = data.create_group(name)
                n = len(traj)
                obs = {"observation": traj.observation, "achieved_goal": traj.achieved_goal,
                       "desired_goal": traj.desired_goal}
                for cam in cameras:  # robomimic's image modality: keys ending in "_image", (N, H, W, 3) uint8
                    obs[f"{cam}_image"] = traj.images[cam]
                for key, values in obs.items():
                    demo.create_dataset(f"obs/{key}", data=values[:-1])
                    demo.create_dataset(f"next_obs/{key}", data=values[1:])
                dones = traj.terminated.astype(np.int64)
                dones[-1] = 1  # robomimic marks the end of each demo as done
                demo.create_dataset("actions", data=traj.action)
                demo.create_dataset("rewards", data=traj.reward.astype(np.float64))
                demo.create_dataset("dones", data=dones)
                demo.create_dataset("states", data=traj.observation[:-1])
                if traj.policy_action is not None:   # robomimic reads none of these; HIL learners (HG-DAgger) do
                    arms = traj.flags[INTERVENTION].reshape(n, -1)
                    demo.create_dataset("is_intervention", data=arms.any(axis=1).astype(np.float32))
                    demo.create_dataset("intervention_arms", data=arms.astype(np.uint8))
                    demo.create_dataset("policy_actions", data=traj.policy_action)
                demo.attrs["num_samples"] = n
                demo.attrs["episode_index"] = int(ep)
                row = rows.loc[ep]
                for key in PROVENANCE_COLUMNS:
                    value = row[key]
                    demo.attrs[key] = value.item() if isinstance(value, np.generic) else value
                total += n
                split = "train" if ep in is_train else "valid"
                masks[split].append(name)
                for key in (mask_name("skill", row["skill"]), mask_name("operator", row["operator_id"]),
                            mask_name("source", row["source"])) + (("successful",) if bool(row["success"]) else ()):
                    masks.setdefault(key, []).append(name)
                    masks.setdefault(f"{key}_{split}", []).append(name)
            data.attrs["total"] = total
            env_kwargs = {}
            if cameras:  # rollouts inside robomimic need the same image in the observation
                h, w = reader.features[f"observation.images.{cameras[0]}"]["shape"][:2]
                env_kwargs = {"camera": True, "camera_size": [int(w), int(h)]}
            data.attrs["env_args"] = json.dumps({"env_name": env_id, "type": GYM_ENV_TYPE, "env_kwargs": env_kwargs})
            data.attrs["surrol_data"] = json.dumps({"source": str(Path(src).resolve()), "where": where or "",
                                                    "task": side.get("task", ""), "split_seed": seed,
                                                    "valid_fraction": valid_fraction})
            group = f.create_group("mask")
            for key, names in sorted(masks.items()):
                group.create_dataset(key, data=np.array(names, dtype="S"))
    except BaseException as e:
        tmp.unlink(missing_ok=True)
        if fh is not None and fh.error is not None and not isinstance(e, OSError):
            raise fh.error from e   # HDF5's "driver write request failed": the disk's error is the cause
        raise
    tmp.replace(out)  # a half-written export never carries the final name
    return out


class _WritesThrough:
    """The file HDF5 writes through, keeping the first error of its writes: HDF5 reports a failed write as a
    RuntimeError ("driver write request failed", often only when the file is closed) that names no cause."""

    def __init__(self, raw):
        self.raw, self.error = raw, None

    def __getattr__(self, name):
        return getattr(self.raw, name)

    def _kept(self, call, *args):
        try:
            return call(*args)
        except OSError as e:
            self.error = self.error or e
            raise

    def write(self, data):
        return self._kept(self.raw.write, data)

    def flush(self):
        return self._kept(self.raw.flush)

    def truncate(self, *size):
        return self._kept(self.raw.truncate, *size)

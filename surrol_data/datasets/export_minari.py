"""Export a dataset to Minari (0.5.x) through the ``minari`` package itself.

Each episode becomes a :class:`minari.data_collector.EpisodeBuffer` — ``observations`` a dict of ``observation`` /
``achieved_goal`` / ``desired_goal`` with N+1 entries (the reset observation first), ``actions`` (N, A),
``rewards`` (N,), ``terminations`` (the env's terminated), ``truncations`` (True at the last step unless it
terminated), ``infos["is_success"]`` (N+1; False at reset) — and :func:`minari.create_dataset_from_buffers`
writes Minari's layout. The episode's provenance goes in as Minari episode metadata (read back with
``dataset.storage.get_episode_metadata``). An intervention session's episodes (``collect --source intervene``) also
carry ``infos["is_intervention"]`` (N+1, bool) and ``infos["policy_action"]`` (N+1, A): who acted at each step and
what the policy proposed (False / zeros at reset).

Where it lands: ``--out DIR`` is used as ``MINARI_DATASETS_PATH``, so the files are
``DIR/<namespace>/<dataset name>-v<k>/data/{metadata.json, main_data.hdf5}`` and
``MINARI_DATASETS_PATH=DIR python -c "import minari; minari.load_dataset('<id>')"`` reads them.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from tqdm import tqdm

from surrol_data.datasets.episode_ranges import chosen_episodes
from surrol_data.datasets.info import read_sidecar
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import PROVENANCE_COLUMNS, package_version
from surrol_data.datasets.trajectory import INTERVENTION


@contextmanager
def _minari_root(path: Path):
    # minari resolves MINARI_DATASETS_PATH on each call; restore the caller's value afterwards.
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous


def _registered_spec(env_id: str):
    """The env's gymnasium spec, so ``dataset.recover_environment()`` works; None if it is not registered."""
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401  (registers the ids)

    return gym.spec(env_id) if env_id in gym.registry else None


def _intervention_infos(traj) -> dict:
    """Who acted and the policy's proposal, aligned with Minari's N+1 infos (the reset entry first)."""
    if traj.policy_action is None:
        return {}
    acted = traj.flags[INTERVENTION].reshape(len(traj), -1).any(axis=1)
    return {"is_intervention": np.concatenate([[False], acted]),
            "policy_action": np.concatenate([np.zeros((1, traj.policy_action.shape[1]), np.float32),
                                             traj.policy_action])}


def default_dataset_id(task: str, name: str) -> str:
    """``surrol/<task>/<name>-v0``: Minari's (namespace/)(env_name/)dataset_name-v<k> syntax."""
    safe = "".join(c if c.isalnum() or c in "-_" else "-" for c in name).strip("-") or "demos"
    return f"surrol/{task or 'task'}/{safe}-v0"


def export_minari(src: str | Path, out: str | Path, *, dataset_id: str | None = None, where: str | None = None,
                  author: str | None = None, progress: bool = True, episodes: list[int] | None = None):
    """Write the episodes of ``src`` (matching ``where``, listed in ``episodes``) as the Minari dataset
    ``dataset_id`` under ``out``. The state, goals, actions and rewards only: camera frames are not exported.

    Returns the :class:`minari.MinariDataset`. ``out`` becomes the datasets root (see the module docstring).
    """
    import gymnasium as gym

    from surrol_data.extras import require

    minari = require("minari")
    from minari.data_collector import EpisodeBuffer

    from surrol_data.datasets.guard import require_valid

    # cheap checks: a damaged dataset is refused before anything is written (read: a read-only one's repaired view)
    reader = DatasetReader(require_valid(src))
    episodes = chosen_episodes(reader, where, episodes)
    if not episodes:
        raise DatasetError(f"no episode of {src} to export" + (f" matches --where {where!r}" if where else ""))
    side = read_sidecar(src)
    task = side.get("task") or str(reader.episodes["task"].iloc[0])
    dataset_id = dataset_id or default_dataset_id(task, Path(src).resolve().name)
    out = Path(out).resolve()  # minari 0.5.4 computes dataset_size wrongly from a relative root
    out.mkdir(parents=True, exist_ok=True)

    f = reader.features
    box = lambda dim: gym.spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32)  # noqa: E731
    goal_dim = int(f["observation.environment_state"]["shape"][0]) // 2  # achieved goal, then desired goal
    observation_space = gym.spaces.Dict({"observation": box(int(f["observation.state"]["shape"][0])),
                                         "achieved_goal": box(goal_dim), "desired_goal": box(goal_dim)})
    action_space = gym.spaces.Box(-1.0, 1.0, shape=tuple(f["action"]["shape"]), dtype=np.float32)

    rows = reader.episodes.set_index("episode_index")
    buffers, metadata = [], []
    for i, ep in enumerate(tqdm(episodes, desc=f"export minari {dataset_id}", unit="ep", disable=not progress)):
        traj = reader.trajectory(ep)
        row = rows.loc[ep]
        truncations = np.zeros(len(traj), bool)
        truncations[-1] = not bool(traj.terminated[-1])
        buffers.append(EpisodeBuffer(
            id=i, seed=int(row["seed"]),
            observations={"observation": traj.observation, "achieved_goal": traj.achieved_goal,
                          "desired_goal": traj.desired_goal},
            actions=traj.action, rewards=traj.reward.astype(np.float64).tolist(),
            terminations=traj.terminated.tolist(), truncations=truncations.tolist(),
            infos={"is_success": np.concatenate([[False], traj.success]), **_intervention_infos(traj)}))
        meta = {k: (row[k].item() if isinstance(row[k], np.generic) else row[k]) for k in PROVENANCE_COLUMNS}
        meta["episode_index"] = int(ep)
        metadata.append(meta)

    with _minari_root(out):
        if dataset_id in minari.list_local_datasets():
            raise FileExistsError(f"Minari dataset {dataset_id!r} already exists under {out}; choose another "
                                  "--dataset-id or --out")
        dataset = minari.create_dataset_from_buffers(
            dataset_id=dataset_id, buffer=buffers, env=_registered_spec(side.get("env_id", "")),
            observation_space=observation_space, action_space=action_space,
            algorithm_name=f"surrol_data {side.get('task', '')} demonstrations ({', '.join(sorted(set(rows['source'])))})",
            author=author or "surrol_data", data_format="hdf5",
            description=f"Exported from {Path(src).resolve()} by surrol_data {package_version()}"
                        + (f" (episodes where {where})" if where else "") + f"; env id {side.get('env_id', '')}.",
        )
        dataset.storage.update_episode_metadata(metadata, episode_indices=range(len(metadata)))
    return dataset

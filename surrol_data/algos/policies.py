"""A policy from a spec on the command line: ``"oracle"``, ``"lerobot:DIR"``, ``"robomimic:CKPT"`` or a checkpoint path.

Evaluation takes any callable ``obs_dict -> action`` (:mod:`surrol_data.evaluation.rollout`); turning a spec into
one belongs here, with the learners whose checkpoints it loads (the CLI, the demo and the study call it).
"""

from __future__ import annotations

from pathlib import Path

from surrol_data.collect.rollout import ORACLE, Policy


def load_policy(spec: str | Path) -> Policy | str:
    """``"oracle"`` stays the string (it is bound to an env at rollout time); ``"lerobot:DIR"`` is a policy trained
    by ``lerobot-train`` (:mod:`surrol_data.evaluation.lerobot_policy`); anything else is a BC checkpoint path."""
    if str(spec) == ORACLE:
        return ORACLE
    if str(spec).startswith("lerobot:"):
        from surrol_data.evaluation.lerobot_policy import load_lerobot_policy

        return load_lerobot_policy(str(spec))
    if str(spec).startswith("robomimic:"):
        from surrol_data.evaluation.robomimic_policy import load_robomimic_policy

        return load_robomimic_policy(str(spec))
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"policy spec {str(spec)!r} is neither {ORACLE!r}, lerobot:DIR, robomimic:CKPT nor an "
                                "existing checkpoint file")
    from surrol_data.algos.bc import BCPolicy  # only checkpoint users pay for importing torch

    return BCPolicy.load(path)


def describe_policy(spec: str | Path) -> dict:
    """What an episode's provenance records of the policy ``spec`` (an intervention session's policy): the spec and
    resolved path, the SHA-256 of its weights, the algorithm, and the provenance of its training data where its
    training run recorded it (the run's ``config.json`` beside ``policy.pt``: the demos' dataset, selection and
    episodes, with those episodes' sources, operators and content hashes while the dataset is there to read)."""
    import hashlib
    import json

    if str(spec) == ORACLE:
        return {"spec": ORACLE, "algorithm": "scripted oracle"}

    def sha256(path: Path) -> str:
        digest = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        return digest.hexdigest()

    if str(spec).startswith("lerobot:"):
        from surrol_data.evaluation.lerobot_policy import pretrained_dir

        folder = pretrained_dir(str(spec).removeprefix("lerobot:"))
        config = json.loads((folder / "config.json").read_text())
        info = {"spec": str(spec), "path": str(folder.resolve()), "sha256": sha256(folder / "model.safetensors"),
                "algorithm": f"lerobot {config.get('type', 'unknown')}"}
        train = folder / "train_config.json"
        if train.is_file():
            dataset = json.loads(train.read_text()).get("dataset", {})
            info["training_data"] = {k: dataset.get(k) for k in ("repo_id", "root", "episodes")}
        return info
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"policy spec {str(spec)!r} is neither {ORACLE!r}, lerobot:DIR nor an existing "
                                "checkpoint file")
    from surrol_data.algos.bc import CHECKPOINT_FORMAT

    info = {"spec": str(spec), "path": str(path.resolve()), "sha256": sha256(path), "algorithm": CHECKPOINT_FORMAT}
    run_config = path.parent / "config.json"
    try:
        config = json.loads(run_config.read_text())
    except (OSError, json.JSONDecodeError):
        return info            # a checkpoint on its own (e.g. `surrol-data train-bc`): no record of its training data
    info["algorithm"] = str(config.get("learner", CHECKPOINT_FORMAT))
    demos, episodes = config.get("demos") or {}, config.get("demo_episodes") or []
    info["training_data"] = {"demos": demos, "demo_episodes": episodes, **_demo_provenance(demos.get("path"), episodes)}
    return info


def _demo_provenance(root, episodes: list[int]) -> dict:
    """Who made the demos a policy was trained on, read from their dataset ({} once it is gone or unreadable):
    episodes per (source, skill, operator) and one hash of the demos' content hashes."""
    if not root or not episodes:
        return {}
    import hashlib

    from surrol_data.datasets.errors import DatasetError
    from surrol_data.datasets.reader import DatasetReader

    try:
        rows = DatasetReader(root).episodes
    except (DatasetError, OSError, ValueError):
        return {}
    rows = rows[rows["episode_index"].isin(episodes)]
    keys = [k for k in ("source", "skill", "operator_id") if k in rows.columns]
    counts = rows.groupby(keys).size() if keys else None
    return {"demo_sources": [{**dict(zip(keys, key if isinstance(key, tuple) else (key,), strict=True)),
                              "episodes": int(n)} for key, n in counts.items()] if counts is not None else [],
            # One hash of the demos' content hashes (in episode order): the same demos give it from any copy.
            "demo_set_hash": hashlib.sha256(" ".join(str(h) for h in rows["content_hash"]).encode()).hexdigest()[:32]
            if "content_hash" in rows.columns else ""}

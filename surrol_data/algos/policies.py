"""A policy from a spec on the command line: ``"oracle"``, ``"lerobot:DIR"`` or a checkpoint path.

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
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"policy spec {str(spec)!r} is neither {ORACLE!r}, lerobot:DIR nor an existing "
                                "checkpoint file")
    from surrol_data.algos.bc import BCPolicy  # only checkpoint users pay for importing torch

    return BCPolicy.load(path)

"""Choose demonstration episodes by provenance and read them through the dataset reader.

``demos=expert`` in the Hydra app becomes ``DemoSpec(path=..., where={"skill": "expert"}, num=100)``: the
first ``num`` episodes (in dataset order) of ``path`` whose provenance matches ``where`` — and, by default,
that succeeded — read as :class:`~surrol_data.datasets.trajectory.Trajectory` objects.

``frames`` chooses which steps of those episodes the learner sees (learning from interventions, issue 31):
``all`` (the default: every step, as before frame selection existed), ``human`` (the steps a person drove: whole
episodes recorded without a policy, and the takeover segments of intervention sessions — HG-DAgger's aggregate
data) or ``intervention`` (the takeover segments only). Each takeover segment becomes a short trajectory of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import sys
from pathlib import Path

from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.trajectory import Trajectory


@dataclass
class DemoSpec:
    path: str | None = None            # LeRobot v3 dataset folder; None = no demos
    where: dict = field(default_factory=dict)  # provenance column -> value or list of accepted values
    num: int = 100                     # episodes to use (the first ones that match)
    successful_only: bool = True
    frames: str = "all"                # all | human | intervention (see the module docstring)


FRAME_SELECTIONS = ("all", "human", "intervention")


def select_frames(trajectories: list[Trajectory], episodes: list[int], frames: str) -> tuple[list[Trajectory], list[int]]:
    """The trajectories (and their episode indices, repeated per segment) that ``frames`` keeps of ``trajectories``."""
    from surrol_data.datasets.interventions import takeover_spans, trajectory_span
    from surrol_data.datasets.trajectory import INTERVENTION

    if frames not in FRAME_SELECTIONS:
        raise ValueError(f"demos.frames must be one of {', '.join(FRAME_SELECTIONS)}, got {frames!r}")
    if frames == "all":
        return trajectories, episodes
    kept, kept_eps = [], []
    for traj, ep in zip(trajectories, episodes, strict=True):
        flags = traj.flags.get(INTERVENTION)
        if flags is None:           # a whole demonstration: every step is the person's
            if frames == "human":
                kept.append(traj)
                kept_eps.append(ep)
            continue
        for start, end in takeover_spans(flags):
            kept.append(trajectory_span(traj, start, end))
            kept_eps.append(ep)
    return kept, kept_eps


def load_demos(spec: DemoSpec, env_id: str | None = None) -> tuple[list[Trajectory], list[int]]:
    """(trajectories, episode indices) selected by ``spec``; empty lists when ``spec.path`` is None.

    ``env_id``: refuse demos recorded on another task (their observation layout would not match).
    """
    if spec.path is None:
        return [], []
    if spec.frames not in FRAME_SELECTIONS:
        raise ValueError(f"demos.frames must be one of {', '.join(FRAME_SELECTIONS)}, got {spec.frames!r}")
    if spec.num < 1:
        raise ValueError(f"demos.num must be >= 1, got {spec.num} (use demos=none to train without demos)")
    root = Path(spec.path)
    if not root.exists():
        raise FileNotFoundError(
            f"demo dataset {root} does not exist. Record one, e.g. `surrol-data collect --source script "
            f"--task NeedlePick --num-episodes 100 --out {root}`, or point demos.path at an existing dataset")
    from surrol_data.datasets.guard import require_valid

    require_valid(root)  # cheap checks: never train on a damaged or half-written dataset
    reader = DatasetReader(root)
    where = {str(k): (list(v) if isinstance(v, (list, tuple)) else v) for k, v in dict(spec.where).items()}
    if spec.successful_only:
        where.setdefault("success", True)
    if env_id is not None and "env_id" in reader.episodes.columns:
        recorded = set(reader.episodes["env_id"])
        if env_id not in recorded:
            raise ValueError(f"demo dataset {root} holds episodes of {sorted(recorded)}, not of {env_id}; "
                             "pick the dataset of the task being trained")
        where.setdefault("env_id", env_id)
    episodes = reader.select(where)
    if len(episodes) < spec.num:
        counts = reader.episodes.groupby(["source", "skill"]).size().to_dict() \
            if {"source", "skill"} <= set(reader.episodes.columns) else {}
        if not episodes:
            raise ValueError(f"demos: no episode of {root} matches {where}; record some or pick another demos= "
                             f"(episodes by (source, skill): {counts})")
        # Fewer than asked (e.g. 20 human demos, demos.num=100): train on what exists, and say so.
        print(f"warning: demos.num={spec.num} but only {len(episodes)} episodes of {root} match {where}; "
              f"using those {len(episodes)}", file=sys.stderr)
    chosen = episodes[: spec.num]
    trajectories, chosen = select_frames(reader.trajectories(chosen), chosen, spec.frames)
    if not trajectories:
        raise ValueError(f"demos.frames={spec.frames}: the {len(episodes[: spec.num])} selected episodes of {root} "
                         "hold no such frames (no operator took over); use demos.frames=all or record interventions "
                         "with `surrol-data collect --source intervene`")
    return trajectories, chosen

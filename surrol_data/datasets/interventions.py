"""Who acted in an intervention session, counted per episode: takeovers, intervention frames, time to takeover.

An intervention session (``surrol-data collect --source intervene``) records at every frame which arms the operator
drove (``complementary_info.intervention_arms``; ``is_intervention`` is their union, LeRobot's HIL-SERL flag). The
counts are derived from that column, the one record of who acted, so they are the same wherever the episode is
read (the session's summary, ``info``, ``assess``, a merged copy).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from surrol_data.datasets.schema import FPS, INTERVENTION_ARMS
from surrol_data.datasets.trajectory import INTERVENTION, Trajectory


@dataclass(frozen=True)
class InterventionCounts:
    takeovers: int              # times an arm passed from the policy to the operator (each arm counted)
    intervention_frames: int    # frames in which the operator drove at least one arm
    frames: int                 # frames of the episode
    time_to_takeover_s: float   # from the episode's start to the first takeover; nan when the policy never lost it
    arm_takeovers: tuple[int, ...] = ()             # per arm (PSM1, PSM2): its takeovers ...
    arm_intervention_frames: tuple[int, ...] = ()   # ... and the frames the operator drove it

    @property
    def intervention_share(self) -> float:
        return self.intervention_frames / self.frames if self.frames else math.nan

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(arm_takeovers=list(self.arm_takeovers), arm_intervention_frames=list(self.arm_intervention_frames))
        return {**d, "intervention_share": self.intervention_share}


def intervention_counts(intervention: np.ndarray, period_s: float = 1.0 / FPS) -> InterventionCounts:
    """Counts of one episode's ``intervention`` flags, (T,) or (T, n_arms) bool."""
    flags = np.asarray(intervention, bool)
    flags = flags.reshape(len(flags), -1)
    # A takeover is a frame the operator drives an arm that the policy drove the frame before (or the first frame).
    before = np.vstack([np.zeros((1, flags.shape[1]), bool), flags[:-1]])
    per_arm = np.sum(flags & ~before, axis=0)
    any_arm = flags.any(axis=1)
    first = int(np.argmax(any_arm)) if any_arm.any() else -1
    return InterventionCounts(takeovers=int(per_arm.sum()), intervention_frames=int(any_arm.sum()), frames=len(flags),
                              time_to_takeover_s=first * period_s if first >= 0 else math.nan,
                              arm_takeovers=tuple(int(n) for n in per_arm),
                              arm_intervention_frames=tuple(int(n) for n in flags.sum(axis=0)))


def trajectory_interventions(traj) -> InterventionCounts | None:
    """:func:`intervention_counts` of a :class:`~surrol_data.datasets.trajectory.Trajectory`; None when it was not
    recorded in an intervention session."""
    flags = traj.flags.get(INTERVENTION)
    return None if flags is None else intervention_counts(flags)


def episode_interventions(reader) -> pd.DataFrame | None:
    """Per episode of a dataset (a :class:`~surrol_data.datasets.reader.DatasetReader`): ``episode_index`` and the
    counts of :class:`InterventionCounts`; None when the dataset was not recorded in intervention sessions."""
    if INTERVENTION_ARMS not in reader.features:
        return None
    rows = []
    for ep, traj in zip(reader.episodes["episode_index"], reader.trajectories(), strict=True):
        rows.append({"episode_index": int(ep), **intervention_counts(traj.flags[INTERVENTION]).as_dict()})
    return pd.DataFrame(rows, columns=["episode_index", "takeovers", "intervention_frames", "frames",
                                       "time_to_takeover_s", "intervention_share", "arm_takeovers",
                                       "arm_intervention_frames"])


def operator_interventions(episodes: pd.DataFrame, by: list[str]) -> list[dict]:
    """Per group of ``episodes`` (provenance rows joined with :func:`episode_interventions`): episodes, takeovers
    (total, per arm and per episode), the share of frames the operator drove, and the mean time to the first
    takeover (over the episodes that had one)."""
    groups = []
    for key, rows in episodes.groupby(by, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        first = rows["time_to_takeover_s"].dropna()
        per_arm = np.sum([list(a) for a in rows["arm_takeovers"]], axis=0) if "arm_takeovers" in rows else []
        groups.append({**dict(zip(by, key, strict=True)), "episodes": int(len(rows)),
                       "takeovers": int(rows["takeovers"].sum()),
                       "arm_takeovers": [int(n) for n in np.atleast_1d(per_arm)],
                       "takeovers_per_episode": float(rows["takeovers"].mean()),
                       "intervention_share": float(rows["intervention_frames"].sum()
                                                   / max(int(rows["frames"].sum()), 1)),
                       "time_to_takeover_s": float(first.mean()) if len(first) else math.nan})
    return groups


def takeover_spans(intervention: np.ndarray) -> list[tuple[int, int]]:
    """The ``[start, end)`` step ranges in which the operator drove at least one arm (``intervention``: (T,) or
    (T, n_arms) bool), in order: the takeover segments that HG-DAgger adds to the imitation data."""
    any_arm = np.asarray(intervention, bool).reshape(len(intervention), -1).any(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], any_arm.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def trajectory_span(traj: Trajectory, start: int, end: int) -> Trajectory:
    """Steps ``[start, end)`` of ``traj`` as a trajectory of their own: the observations before each of those
    actions and the one after the last (so a segment is a short episode, with its own HER goals)."""
    if not 0 <= start < end <= len(traj):
        raise ValueError(f"span [{start}, {end}) is not within the trajectory's {len(traj)} steps")
    steps, states = slice(start, end), slice(start, end + 1)
    return Trajectory(
        observation=traj.observation[states], achieved_goal=traj.achieved_goal[states],
        desired_goal=traj.desired_goal[states], action=traj.action[steps], reward=traj.reward[steps],
        success=traj.success[steps], terminated=traj.terminated[steps], tip_position=traj.tip_position[states],
        jaw_angle=traj.jaw_angle[states], flags={k: v[steps] for k, v in traj.flags.items()},
        images={k: v[states] for k, v in traj.images.items()},
        policy_action=None if traj.policy_action is None else traj.policy_action[steps])

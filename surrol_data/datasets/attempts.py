"""Grasp attempts, failed attempts and retries of one trajectory — what a recovery measure must see.

A jaw command that flickers below zero on the way to the object is not a grasp, and counting every open→close
transition as one (:func:`surrol_data.datasets.metrics.failed_grasps`) makes a jittery policy look as if it
retried. The rules here count only what a person watching would call an attempt:

* **attempt**: a run of commanded jaw < 0 (the jaw command, the last action dimension of the arm) lasting at least
  :data:`ATTEMPT_MIN_STEPS` actions, during which the measured jaw closes by at least :data:`JAW_CLOSING_RAD`, and
  which starts with the tool tip within :data:`NEAR_M` of the object's grasp point (NeedlePick: the needle's
  mid-arc point the oracle grasps, not its centre) — at the command's first state or after its first action. A
  run that held the object is an attempt whatever the distance (a grasp that happened was aimed);
* **failed attempt**: the object was never held during it, or its hold ended before the object had been lifted
  :data:`LIFT_M` above its height at the attempt's start (released, slipped or dropped). A hold that lasts to the
  episode's end was not lost;
* **retry**: an attempt that follows a failed attempt (the jaw opened in between: the next attempt's jaw closes
  again by :data:`JAW_CLOSING_RAD`);
* **episode outcome** (:class:`Outcome`): the first attempt held; it failed and a retry came, and the episode ended
  in success (recovered) or not; it failed and no retry came (a stall, the paper's script failure); or no attempt.

Inputs per episode of T actions (the trajectory convention): ``jaw_command`` (T,), ``grasped`` (T,) — held after
action ``t``; ``jaw_angle``, ``tip_position`` and ``grasp_point`` (T+1, ...) — the reset state first, metres and
radians; ``final_success`` — success at the last step. Policy rollouts (training's evaluation, ``evaluate``) and
recorded demos give all of them through :class:`~surrol_data.datasets.trajectory.Trajectory`
(:func:`trajectory_attempts`): the jaw command is ``action[:, 4]``, the measured jaw ``jaw_angle`` (the dataset's
``complementary_info.jaw_angle``), the tip ``tip_position`` (``complementary_info.tip_position``), held the event flag
``grasped`` (``complementary_info.grasped``; datasets recorded before the event flags existed lack it: the measure is
then unknown, None) and the grasp point the observation's object waypoint (``observation.state``'s
``<object>_waypoint_x/y/z``, dimensions 13–15 of a one-arm object task; for NeedlePick also the achieved goal, the
first three terms of ``observation.environment_state``). The object's height is the grasp point's z.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

ATTEMPT_MIN_STEPS = 2       # a one-step close is a flicker, not an aimed grasp
JAW_CLOSING_RAD = 0.1       # the measured jaw must close this much (the jaw moves 0.8 rad per 0.2 s step)
NEAR_M = 0.005              # the tip within 5 mm of the grasp point when the close begins
LIFT_M = 0.005              # the reference's lift condition: a hold that lifted the object 5 mm is a grasp
# One-arm object tasks: the object's waypoint (the grasp point) in the observation (envs/names.py's layout:
# tip xyz, tip rpy, jaw, object xyz, object from tip, object waypoint, object rpy).
WAYPOINT_DIMS = slice(13, 16)
ONE_ARM_OBJECT_OBS_DIM = 19


class Outcome(str, Enum):
    FIRST_HELD = "first_held"                  # the first attempt held the object
    RECOVERED = "retried_recovered"            # first attempt failed, a retry came, the episode succeeded
    NOT_RECOVERED = "retried_not_recovered"    # first attempt failed, a retry came, the episode failed
    STALL = "stall"                            # first attempt failed, no retry
    NO_ATTEMPT = "no_attempt"                  # never closed the jaw near the grasp point


@dataclass(frozen=True)
class Attempt:
    start: int      # index of the first action of the closed run
    end: int        # one past its last action
    held: bool      # the object was held at some step of it
    lifted: bool    # while held, the object rose LIFT_M above its height at the start
    failed: bool    # never held, or lost before the lift
    retry: bool     # it follows a failed attempt


@dataclass(frozen=True)
class EpisodeAttempts:
    """The attempts of one episode and its outcome."""
    attempts: tuple[Attempt, ...]
    outcome: Outcome

    @property
    def n_attempts(self) -> int:
        return len(self.attempts)

    @property
    def n_failed(self) -> int:
        return sum(a.failed for a in self.attempts)

    @property
    def n_retries(self) -> int:
        return sum(a.retry for a in self.attempts)

    def as_row(self) -> dict:
        """The per-episode columns a report pools (``eval_episodes.csv``)."""
        return {"attempts": self.n_attempts, "failed_attempts": self.n_failed, "retries": self.n_retries,
                "attempt_outcome": self.outcome.value}


def closed_runs(jaw_command: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) of every run of jaw command < 0, end exclusive."""
    closed = np.asarray(jaw_command, np.float64).reshape(-1) < 0
    edges = np.flatnonzero(np.diff(np.concatenate([[False], closed, [False]]).astype(np.int8)))
    return [(int(s), int(e)) for s, e in zip(edges[0::2], edges[1::2])]


def find_attempts(jaw_command, jaw_angle, tip_position, grasp_point, grasped) -> tuple[Attempt, ...]:
    """The attempts of one episode (see the module docstring for the rules and the shapes)."""
    cmd = np.asarray(jaw_command, np.float64).reshape(-1)
    n = len(cmd)
    jaw = np.asarray(jaw_angle, np.float64).reshape(n + 1, -1)[:, 0]
    tip = np.asarray(tip_position, np.float64).reshape(n + 1, -1)[:, :3]
    point = np.asarray(grasp_point, np.float64).reshape(n + 1, -1)[:, :3]
    held = np.asarray(grasped, bool).reshape(n, -1)[:, 0]
    distance = np.linalg.norm(tip - point, axis=1)
    attempts: list[Attempt] = []
    for start, end in closed_runs(cmd):
        was_held = bool(held[start:end].any())
        closing = jaw[start] - jaw[start + 1:end + 1].min() >= JAW_CLOSING_RAD
        near = distance[start:start + 2].min() <= NEAR_M
        if not was_held and not (end - start >= ATTEMPT_MIN_STEPS and closing and near):
            continue
        held_steps = np.flatnonzero(held[start:end]) + start
        # the object's height after each held action, against its height when the close began
        lifted = bool(was_held and (point[held_steps + 1, 2] - point[start, 2]).max() >= LIFT_M - 1e-9)
        # the hold ended: lost while the jaw stayed closed, or released when it opened before the episode ended
        hold_ended = was_held and (int(held_steps[-1]) < end - 1 or end < n)
        failed = not was_held or (not lifted and hold_ended)
        retry = bool(attempts) and attempts[-1].failed
        attempts.append(Attempt(start, end, was_held, lifted, bool(failed), retry))
    return tuple(attempts)


def outcome(attempts: tuple[Attempt, ...], final_success: bool) -> Outcome:
    if not attempts:
        return Outcome.NO_ATTEMPT
    if not attempts[0].failed:
        return Outcome.FIRST_HELD
    if len(attempts) == 1:
        return Outcome.STALL
    return Outcome.RECOVERED if final_success else Outcome.NOT_RECOVERED


def episode_attempts(jaw_command, jaw_angle, tip_position, grasp_point, grasped,
                     final_success: bool) -> EpisodeAttempts:
    found = find_attempts(jaw_command, jaw_angle, tip_position, grasp_point, grasped)
    return EpisodeAttempts(found, outcome(found, bool(final_success)))


def grasp_point_of(observation: np.ndarray) -> np.ndarray | None:
    """The object's grasp point (T+1, 3) from a one-arm object task's observation; None for other layouts."""
    obs = np.asarray(observation)
    if obs.ndim != 2 or obs.shape[1] != ONE_ARM_OBJECT_OBS_DIM:
        return None
    return obs[:, WAYPOINT_DIMS]


def trajectory_attempts(traj) -> EpisodeAttempts | None:
    """The attempts of a :class:`~surrol_data.datasets.trajectory.Trajectory` (a rollout or a recorded demo) of a
    one-arm object task; None when it carries no grasp record or no grasp point (another layout)."""
    point = grasp_point_of(traj.observation)
    held = traj.flags.get("grasped")
    act = np.asarray(traj.action)
    if point is None or held is None or act.ndim != 2 or act.shape[1] != 5:
        return None
    return episode_attempts(act[:, 4], traj.jaw_angle, traj.tip_position, point, held, traj.final_success)

"""The attempt/retry measure on synthetic trajectories (each rule alone), and on a real NeedlePick oracle episode."""

from __future__ import annotations

import numpy as np
import pytest

from surrol_data.datasets.attempts import (LIFT_M, Outcome, closed_runs, episode_attempts, find_attempts,
                                           trajectory_attempts)

OPEN, CLOSED = np.deg2rad(40.0), 0.0
POINT = np.array([0.0, 0.0, 0.70])   # the grasp point at rest


class Episode:
    """A synthetic one-arm episode built step by step: the jaw follows its command within one step (as the env's
    does: 0.8 rad per step), the grasp point moves up by ``lift`` while held."""

    def __init__(self, tip=(0.03, 0.0, 0.73)):
        self.cmd, self.held = [], []
        self.tip, self.jaw, self.point = [np.array(tip, float)], [OPEN], [POINT.copy()]

    def step(self, close: bool, tip=None, held: bool = False, lift: float = 0.0, n: int = 1) -> Episode:
        for _ in range(n):
            self.cmd.append(-0.5 if close else 0.5)
            self.held.append(held)
            self.jaw.append(CLOSED if close else OPEN)
            self.tip.append(np.array(tip, float) if tip is not None else self.tip[-1])
            point = self.point[-1].copy()
            point[2] = POINT[2] + lift if held else POINT[2]
            self.point.append(point)
        return self

    def arrays(self):
        return (np.array(self.cmd), np.array(self.jaw), np.array(self.tip), np.array(self.point),
                np.array(self.held))

    def measure(self, final_success: bool = False):
        return episode_attempts(*self.arrays(), final_success)


NEAR = (0.001, 0.0, 0.70)        # 1 mm from the grasp point
FAR = (0.03, 0.01, 0.72)         # 3.3 cm away
BACKED_OFF = (0.0, 0.0, 0.715)   # 1.5 cm above it


def test_closed_runs():
    assert closed_runs(np.array([1, -1, -1, 1, -1, 0, -1])) == [(1, 3), (4, 5), (6, 7)]
    assert closed_runs(np.ones(4)) == []


def test_flicker_away_from_the_needle_is_no_attempt():
    ep = Episode(tip=FAR)
    for _ in range(5):   # a jittery policy on its way: one- and two-step closes, 3 cm from the needle
        ep.step(True).step(False).step(True, n=2).step(False)
    ep.step(True, tip=NEAR).step(False, tip=NEAR)   # a one-step close at the needle: a flicker too
    record = ep.measure()
    assert record.n_attempts == 0 and record.outcome is Outcome.NO_ATTEMPT
    # the old measure counts all 11 closures of this episode as failed grasps
    from surrol_data.datasets.metrics import failed_grasps
    assert failed_grasps(ep.arrays()[0], ep.arrays()[4]) == 11


def test_a_close_whose_jaw_does_not_close_is_no_attempt():
    ep = Episode(tip=NEAR).step(True, tip=NEAR, n=3)
    cmd, jaw, tip, point, held = ep.arrays()
    jaw[:] = CLOSED   # the measured jaw was closed already: the command changes nothing
    assert find_attempts(cmd, jaw, tip, point, held) == ()


def test_first_attempt_held_and_lifted():
    ep = Episode().step(False, tip=NEAR, n=3).step(True, tip=NEAR, held=True, n=2)
    ep.step(True, tip=(0.001, 0.0, 0.71), held=True, lift=0.01, n=10)
    record = ep.measure(final_success=True)
    assert record.outcome is Outcome.FIRST_HELD
    assert (record.n_attempts, record.n_failed, record.n_retries) == (1, 0, 0)
    assert record.attempts[0].held and record.attempts[0].lifted


def test_reopen_back_off_reapproach_close_is_a_retry():
    ep = Episode().step(False, tip=NEAR, n=3)
    ep.step(True, tip=NEAR, n=3)                              # 1st attempt: closes beside the wire, holds nothing
    ep.step(False, tip=BACKED_OFF, n=2).step(False, tip=NEAR, n=2)   # reopen, back off, re-approach
    ep.step(True, tip=NEAR, held=True, n=2).step(True, held=True, lift=0.02, n=8)   # 2nd: held and lifted
    record = ep.measure(final_success=True)
    assert (record.n_attempts, record.n_failed, record.n_retries) == (2, 1, 1)
    assert record.attempts[0].failed and not record.attempts[0].held
    assert record.attempts[1].retry and not record.attempts[1].failed
    assert record.outcome is Outcome.RECOVERED
    assert ep.measure(final_success=False).outcome is Outcome.NOT_RECOVERED
    assert record.as_row() == {"attempts": 2, "failed_attempts": 1, "retries": 1,
                               "attempt_outcome": "retried_recovered"}


def test_a_stall_is_a_stall():
    # the script's failure: closes beside the needle, holds nothing, and stays so (jaw closed to the end) ...
    ep = Episode().step(False, tip=NEAR, n=3).step(True, tip=NEAR, n=20)
    assert ep.measure().outcome is Outcome.STALL
    # ... or reopens and hovers, closing only in flickers away from the needle
    ep = Episode().step(False, tip=NEAR, n=3).step(True, tip=NEAR, n=3).step(False, tip=FAR, n=3)
    ep.step(True).step(False).step(True, n=2).step(False, n=5)
    record = ep.measure()
    assert record.outcome is Outcome.STALL and record.n_attempts == 1 and record.n_retries == 0


def test_lost_before_a_5_mm_lift_is_a_failed_attempt():
    def lost_after(lift: float):
        ep = Episode().step(False, tip=NEAR, n=3).step(True, tip=NEAR, held=True, n=2)
        ep.step(True, held=True, lift=lift, n=2).step(True, n=6)   # slips out while the jaw stays closed
        return ep.measure().attempts[0]

    early = lost_after(0.6 * LIFT_M)
    assert early.held and not early.lifted and early.failed
    late = lost_after(2 * LIFT_M)   # a drop in transport, after the lift: the grasp itself held
    assert late.held and late.lifted and not late.failed
    # released (jaw opened) before the lift: lost too
    ep = Episode().step(False, tip=NEAR, n=3).step(True, tip=NEAR, held=True, n=3).step(False, n=3)
    assert ep.measure().attempts[0].failed
    # held, unlifted, to the episode's end: never lost
    ep = Episode().step(False, tip=NEAR, n=3).step(True, tip=NEAR, held=True, n=5)
    assert not ep.measure().attempts[0].failed


def test_a_hold_far_from_the_grasp_point_is_still_an_attempt():
    # grasped 8 mm off the mid-arc point: the measure counts what held, whatever the distance
    ep = Episode().step(False, tip=(0.008, 0.0, 0.70), n=2).step(True, held=True, lift=0.01, n=4)
    assert ep.measure(True).outcome is Outcome.FIRST_HELD


def test_the_needle_centre_is_not_the_grasp_point():
    # a close at the needle's centre (1 cm from its mid-arc grasp point) is no attempt
    ep = Episode().step(False, tip=(0.01, 0.0, 0.70), n=2).step(True, n=3)
    assert ep.measure().n_attempts == 0


@pytest.fixture(scope="module")
def oracle_trajectory():
    from surrol_data.evaluation.rollout import evaluate

    return evaluate("SurRoL/NeedlePick-v0", "oracle", 1, progress=False, keep_trajectories=True).trajectories[0]


def test_a_real_oracle_episode_is_one_held_attempt(oracle_trajectory):
    record = trajectory_attempts(oracle_trajectory)
    assert record is not None and record.outcome is Outcome.FIRST_HELD
    assert record.n_attempts == 1 and record.attempts[0].lifted


def test_a_real_episode_without_grasp_records_is_unknown(oracle_trajectory):
    from dataclasses import replace

    flags = {k: v for k, v in oracle_trajectory.flags.items() if k != "grasped"}
    assert trajectory_attempts(replace(oracle_trajectory, flags=flags)) is None

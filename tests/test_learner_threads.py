"""The batched learner widens to idle cores only when that is measured to make its updates faster."""

import pytest
import torch

from surrol_data.algos.learner_threads import REMEASURE_EVERY, WARMUP, LearnerThreads


@pytest.fixture(autouse=True)
def restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


class FakeMachine:
    """A clock that advances by the update's cost for the thread count it runs with."""

    def __init__(self, seconds_per_update: dict[int, float]):
        self.seconds_per_update, self.now, self.busy = seconds_per_update, 0.0, 0
        self.used: list[int] = []

    def clock(self) -> float:
        return self.now

    def update(self) -> None:
        n = torch.get_num_threads()
        self.used.append(n)
        self.now += self.seconds_per_update[n]


def run(machine: FakeMachine, threads: LearnerThreads, updates: int) -> list[int]:
    start = len(machine.used)
    for _ in range(updates):
        threads.timed(machine.update)
    return machine.used[start:]


def test_the_learner_stays_on_its_base_threads_while_the_workers_play():
    machine = FakeMachine({1: 1.0, 2: 0.5})
    machine.busy = 2
    threads = LearnerThreads(1, lambda: machine.busy, cores=2, clock=machine.clock)
    assert set(run(machine, threads, 20)) == {1}
    assert threads.count == {}   # nothing measured: no choice was made


def test_on_a_quiet_machine_it_takes_the_idle_core_and_now_and_then_re_measures_one_thread():
    machine = FakeMachine({1: 1.0, 2: 0.6})
    threads = LearnerThreads(1, lambda: 0, cores=2, clock=machine.clock)
    used = run(machine, threads, 4 * REMEASURE_EVERY)
    assert used[:2 * WARMUP].count(2) == WARMUP and used[:2 * WARMUP].count(1) == WARMUP
    settled = used[2 * WARMUP:]
    assert settled.count(1) == pytest.approx(len(settled) / REMEASURE_EVERY, abs=1)
    assert threads.mean[2] < threads.mean[1]


def test_on_a_loaded_machine_where_two_threads_are_slower_it_keeps_one():
    machine = FakeMachine({1: 1.0, 2: 1.8})   # another job's threads on the cores: spinning OpenMP threads lose
    threads = LearnerThreads(1, lambda: 0, cores=2, clock=machine.clock)
    settled = run(machine, threads, 4 * REMEASURE_EVERY)[2 * WARMUP:]
    assert settled.count(2) == pytest.approx(len(settled) / REMEASURE_EVERY, abs=1)


def test_it_follows_the_machine_when_the_load_changes():
    machine = FakeMachine({1: 1.0, 2: 0.6})
    threads = LearnerThreads(1, lambda: 0, cores=2, clock=machine.clock)
    run(machine, threads, 2 * REMEASURE_EVERY)
    machine.seconds_per_update = {1: 1.0, 2: 1.8}   # another job starts
    assert run(machine, threads, 4 * REMEASURE_EVERY)[-2 * REMEASURE_EVERY:].count(1) > 1.5 * REMEASURE_EVERY
    machine.seconds_per_update = {1: 1.0, 2: 0.6}   # and ends
    assert run(machine, threads, 4 * REMEASURE_EVERY)[-2 * REMEASURE_EVERY:].count(2) > 1.5 * REMEASURE_EVERY


def test_widen_false_keeps_the_base_threads_and_measures_nothing():
    machine = FakeMachine({1: 1.0, 2: 0.5})
    threads = LearnerThreads(1, lambda: 0, cores=2, clock=machine.clock, widen=False)
    assert set(run(machine, threads, 20)) == {1}
    assert threads.count == {}

"""How many torch threads the batched learner uses for each update: the cores its env workers leave idle, when
that is measured to help.

In a batched cycle the workers play the episodes while the learner runs updates, and the updates take longer
(paper protocol, 12 members: ~2 s of play against ~6 s of updates on one thread), so with one fixed thread a
core idles for most of every cycle. Once the workers are done, a second thread makes an update ~1.7× faster
on a quiet two-core machine. On a shared one it can make it slower: torch's OpenMP threads spin while they
wait, and two jobs that each widen fight over the cores (measured: two batched sweeps at once, load 6.5). So
the learner measures both settings on its own updates and keeps the faster, re-measuring the other now and
then, as the machine's load changes. Results do not depend on the choice: torch's CPU kernels give
bit-identical updates for any thread count (tests/test_batched.py keeps that true), so the timing-dependent
choice does not break exact resume.
"""

from __future__ import annotations

import os
import time

import torch

# Idle-phase updates between two re-measurements of the setting not in use.
REMEASURE_EVERY = 50
# First measurements of each setting before choosing.
WARMUP = 3
# Weight of a new update's time in a setting's running mean.
SMOOTHING = 0.3


def available_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


class LearnerThreads:
    """Run every update through :meth:`timed`.

    ``busy_workers``: a callable, how many env workers are still playing; ``base``: the threads while they all
    play (the config's ``torch_threads``); ``widen=False``: always ``base``."""

    def __init__(self, base: int, busy_workers, cores: int | None = None, clock=time.perf_counter,
                 widen: bool = True):
        self.base, self.busy_workers, self.clock, self.widen = base, busy_workers, clock, widen
        self.cores = cores or available_cores()
        self.current = torch.get_num_threads()
        self.mean: dict[int, float] = {}     # threads -> running mean seconds per idle-phase update
        self.count: dict[int, int] = {}
        self._idle_updates = 0
        self._timing: tuple[int, float] | None = None

    def timed(self, update, *args):
        self._before_update()
        try:
            return update(*args)
        finally:
            self._after_update()

    def _before_update(self) -> None:
        wide = self.cores - self.busy_workers() if self.widen else self.base
        if wide > self.base:   # a core to spare: choose, and time the update for the next choice
            n = self._choose(wide)
            self._timing = (n, self.clock())
        else:
            n, self._timing = self.base, None
        if n != self.current:
            torch.set_num_threads(n)
            self.current = n

    def _after_update(self) -> None:
        if self._timing is None:
            return
        n, started = self._timing
        seconds = self.clock() - started
        self.mean[n] = seconds if n not in self.mean else (1 - SMOOTHING) * self.mean[n] + SMOOTHING * seconds
        self.count[n] = self.count.get(n, 0) + 1
        self._timing = None

    def _choose(self, wide: int) -> int:
        i = self._idle_updates
        self._idle_updates += 1
        for n in (wide, self.base):
            if self.count.get(n, 0) < WARMUP:
                return n
        faster, slower = (wide, self.base) if self.mean[wide] < self.mean[self.base] else (self.base, wide)
        return slower if i % REMEASURE_EVERY == 0 else faster

"""Scripted rollouts in worker processes, handed back in seed order: :func:`oracle_rollouts`.

``collect --workers N`` rolls the oracle out in N processes while this process records. The recorder stays the
only writer (one lock, one journal: the crash guarantee is the recorder's, unchanged), and it receives the
episodes in exactly the order a single process would produce them — attempt ``i`` is seed ``first + i * stride``
whichever worker ran it — so the kept episodes, their seeds and their frames are those of ``--workers 1``.
A worker rolls out a seed with a fresh ``env.reset(seed=...)``, the same call the single process makes.

Workers are spawned, not forked: the parent has a PyBullet connection open, which a fork would share.
At most ``2 * workers`` seeds are in flight, so the rollouts not needed once enough episodes are kept are few
and are discarded.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterator

from surrol_data.datasets.trajectory import Trajectory

_ENV = None
_POLICY = None


def _start_worker(eid: str, env_kwargs: dict, make_kwargs: dict, speed: float) -> None:
    global _ENV, _POLICY
    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.collect.rollout import ORACLE
    from surrol_data.collect.script_source import PacedOracle, make_env

    _ENV = make_env(eid, env_kwargs, **make_kwargs)
    _POLICY = ORACLE if speed == 1.0 else PacedOracle(_ENV, speed)


def _roll(seed: int) -> tuple[Trajectory, float]:
    from surrol_data.collect.rollout import rollout

    t0 = time.perf_counter()
    traj = rollout(_ENV, _POLICY, seed)
    return traj, time.perf_counter() - t0


def oracle_rollouts(eid: str, env_kwargs: dict, make_kwargs: dict, speed: float, seeds: Iterator[int],
                    workers: int) -> Iterator[tuple[int, Trajectory, float]]:
    """(seed, trajectory, seconds the rollout took) for each seed of ``seeds``, in order, rolled out by ``workers``
    spawned processes. Stop iterating whenever enough episodes are kept: the pool is shut down on close."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_start_worker, initargs=(eid, env_kwargs, make_kwargs, speed))
    pending: deque = deque()
    try:
        for seed in seeds:
            pending.append((seed, pool.submit(_roll, seed)))
            if len(pending) < 2 * workers:
                continue
            done_seed, future = pending.popleft()
            yield done_seed, *future.result()
        while pending:
            done_seed, future = pending.popleft()
            yield done_seed, *future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

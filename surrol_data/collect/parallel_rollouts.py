"""Rollouts in worker processes, handed back in the order they were asked for: :func:`ordered_rollouts`.

``collect --workers N`` rolls the oracle out in N processes while this process records. The recorder stays the
only writer (one lock, one journal: the crash guarantee is the recorder's, unchanged), and it receives the
episodes in exactly the order a single process would produce them — attempt ``i`` is seed ``first + i * stride``
whichever worker ran it — so the kept episodes, their seeds and their frames are those of ``--workers 1``
(each rollout starts from ``env.reset(seed=...)``, the same call the single process makes).

Workers are spawned, not forked: the parent has a PyBullet connection open, which a fork would share.
At most ``ahead`` rollouts (at least ``2 * workers``) are asked for before their results are taken: enough that the
workers go on while the recorder is busy for a while (creating its dataset), few enough that their results fit in
memory; those asked for when enough episodes are kept are cancelled or discarded. A worker whose recording process
was killed (SIGKILL, the OOM killer) exits by itself: an idle worker waits on its task queue forever, each one
holding a simulator.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator

_PARENT_POLL_S = 0.5


def exit_with(parent: int) -> None:
    """A pool worker's initializer: a thread that ends this process once ``parent`` is gone (a pool's worker waits on
    its task queue forever otherwise: the queue's pipe never closes, the worker holds both of its ends)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_PARENT_POLL_S)
        os._exit(1)   # nobody is left to take what this process makes

    threading.Thread(target=watch, name="surrol_data-exit-with-parent", daemon=True).start()


def _start_beside(parent: int, start: Callable, start_args: tuple) -> None:
    exit_with(parent)
    start(*start_args)


def ordered_rollouts(start: Callable, start_args: tuple, roll: Callable, seeds: Iterable[int],
                     workers: int, ahead: int = 0) -> Iterator[tuple]:
    """``(seed, *roll(seed))`` for each seed, in order, computed by ``workers`` spawned processes that each ran
    ``start(*start_args)`` first (both module-level functions, so a spawned process can import them). Stop iterating
    whenever enough is done: closing the iterator shuts the processes down."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_start_beside, initargs=(os.getpid(), start, start_args))
    pending: deque = deque()
    try:
        for seed in seeds:
            pending.append((seed, pool.submit(roll, seed)))
            if len(pending) >= max(ahead, 2 * workers):
                done_seed, future = pending.popleft()
                yield done_seed, *future.result()
        while pending:
            done_seed, future = pending.popleft()
            yield done_seed, *future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

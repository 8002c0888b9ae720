"""The web console's one writer: every browser's kept episodes go through one thread into one dataset per task.

Each session process hands its episode here (:meth:`EpisodeWriter.submit`); the thread records it with the haptic
sessions' :func:`~surrol_data.collect.haptic_source.record_episode` (the device trace, then the episode, through the
crash-safe :class:`~surrol_data.datasets.recorder.DatasetRecorder`, checkpointed after every episode) and answers
the session with the episode's index only once it is durable. A server killed at any moment loses no episode that
was answered; :meth:`close` finalizes the datasets.
"""

from __future__ import annotations

import logging
import queue
import threading
from pathlib import Path

import gymnasium as gym

from surrol_data.collect.haptic_source import record_episode
from surrol_data.collect.script_source import features_for, first_seed
from surrol_data.datasets import lerobot_compat
from surrol_data.datasets.recorder import DatasetRecorder
from surrol_data.envs import env_id
from surrol_data.envs.names import dimension_names

log = logging.getLogger("surrol_data.web")


class EpisodeWriter:
    """One thread, one :class:`DatasetRecorder` per task under ``out`` (``out/<Task>``), opened at its first
    episode (appending to a dataset that exists)."""

    def __init__(self, out: str | Path, command: str = "surrol-data serve"):
        self.out = Path(out)
        self.command = command
        self._recorders: dict[str, DatasetRecorder] = {}
        self._queue: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="surrol-web-writer", daemon=True)
        self._thread.start()
        # lerobot imports meanwhile (in a daemon thread: a server stopped before any episode does not wait for it),
        # so that the first episode saved does not wait for it either.
        lerobot_compat.import_in_background()

    def dataset(self, task: str) -> Path:
        return self.out / task

    def first_seed(self, task: str) -> int:
        """One past the largest seed the task's dataset holds (0 for a new one): sessions start there."""
        return first_seed(self.dataset(task), True, None, "haptic")

    def submit(self, task: str, record: dict, answer) -> None:
        """Record ``record`` (a worker's episode) on the writer's thread; ``answer(("recorded", index))`` once it is
        durable, or ``answer(("record_failed", why))``."""
        self._queue.put((task, record, answer))

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                break
            task, record, answer = item
            try:
                recorder = self._recorder(task)
                index = record_episode(recorder, self.dataset(task), record["traj"], record["provenance"],
                                       record["frames"], record["meta"])
                log.info("recorded episode %d of %s (operator %s)", index, task, record["provenance"]["operator_id"])
                answer(("recorded", index))
            except Exception as e:   # the session says it was not saved; the writer goes on for the others
                log.error("could not record an episode of %s: %s", task, e)
                answer(("record_failed", f"{type(e).__name__}: {e}"))

    def _recorder(self, task: str) -> DatasetRecorder:
        if task not in self._recorders:
            lerobot_compat.wait_for_background_import()
            eid = env_id(task)
            env = gym.make(eid)
            try:
                recorder = DatasetRecorder(self.dataset(task), task=task, env_id=eid,
                                           task_description=env.unwrapped.TASK, features=features_for(env),
                                           append=True, command=self.command, checkpoint_every=1,
                                           robot_type=dimension_names(env).robot_type, lazy=False)
            finally:
                env.close()
            recorder.open()
            self._recorders[task] = recorder
        return self._recorders[task]

    def close(self) -> None:
        """Record what was submitted, then finalize every dataset."""
        self._queue.put(None)
        self._thread.join()
        for recorder in self._recorders.values():
            recorder.close()
        self._recorders.clear()

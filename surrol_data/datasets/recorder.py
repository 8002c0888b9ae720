"""Record trajectories as a LeRobot v3 dataset with per-episode provenance: :class:`DatasetRecorder`.

Usage::

    features = frame_features(obs_dim=19, goal_dim=3, act_dim=5, n_arms=1)
    with DatasetRecorder("datasets/needle_pick", features=features, task="NeedlePick",
                         env_id="SurRoL/NeedlePick-v0", task_description="pick up the needle") as rec:
        for traj, seed in episodes:
            rec.record(traj, {"source": "script", "device": "none", "skill": "scripted", "seed": seed})

The recorder is the :class:`~surrol_data.datasets.writer.DatasetWriter` (what survives a kill, the journal,
checkpoints, the lock: see :mod:`surrol_data.datasets.writer`) that, appending to a dataset a killed recording
left unfinished, repairs it first (:func:`surrol_data.datasets.guard.ensure_finished`, with a message), as every
command does before it trusts a dataset. The repair itself writes through a plain writer.
"""

from __future__ import annotations

from surrol_data.datasets.writer import DatasetWriter


class DatasetRecorder(DatasetWriter):
    """Context manager writing one :class:`~surrol_data.datasets.trajectory.Trajectory` per :meth:`record` call.

    ``root``: the dataset folder. With ``append=False`` it must not exist; with ``append=True`` an
    existing dataset is resumed (and a missing one created; one left unfinished by a killed recording is
    repaired first). ``features`` (from :func:`surrol_data.datasets.schema.frame_features`) is required to
    create, and checked against the dataset when appending. ``task_description`` is LeRobot's natural-language
    per-frame task; ``task`` and ``env_id`` are the defaults of the provenance columns of the same names and go
    into the sidecar.
    """

    def _before_append(self) -> None:
        from surrol_data.datasets.guard import ensure_finished

        ensure_finished(self.root)  # a killed recording is repaired first (with a message)

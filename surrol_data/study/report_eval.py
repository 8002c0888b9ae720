"""What the report stands on at its epochs: each run's kept actors evaluated on fresh episodes, and probed.

Training keeps the actor at epochs 25, 50, 75 and 100 (and the report epochs) in ``actors/epochNNN.pt``
(:func:`~surrol_data.algos.train_batched.actor_path`; ``surrol-data eval --policy`` runs each). Once a run has
trained, each report epoch's actor plays

* ``eval``: ``episodes`` fresh episodes (seeds from :data:`REPORT_SEED_BASE`: disjoint from the demos' small seeds,
  training's ``seed·10⁶ + k`` and the per-epoch evaluation's ``10⁹ + k``), deterministic, as the per-epoch
  evaluation plays them but on 100 episodes instead of a handful;
* ``probe``: as many episodes (seeds from :data:`PROBE_SEED_BASE`) with the grip disabled during its first attempt
  near the grasp point (:class:`~surrol_data.evaluation.grip_probe.InducedFailure`): does it reopen and grasp again?

One row per episode (:func:`~surrol_data.evaluation.episode_rows.episode_row`, with ``epoch``, ``kind``,
``episode``, ``seed``; probe rows add whether the probe disabled an attempt, from which step, how many attempts
followed it and whether it prevented a grip) in
``report_episodes.csv``. Every run and epoch plays the same seeds, so sources compare on the same scenes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from surrol_data.evaluation.recovery_report import REPORT_FILE

REPORT_SEED_BASE = 2_000_000_000
PROBE_SEED_BASE = 2_100_000_000
KEPT_ACTOR_EPOCHS = (25, 50, 75, 100)
# The epochs of the attempts and induced-failure tables (the paper's retry question at the start, middle and end of
# training), evaluated besides the report epochs of Table I.
RECOVERY_EPOCHS = (25, 50, 100)


def actor_epochs(report_epochs: Sequence[int], epochs: int) -> tuple[int, ...]:
    """The epochs whose actor a run of ``epochs`` epochs keeps: 25, 50, 75, 100 and the report epochs."""
    return tuple(sorted(e for e in {*KEPT_ACTOR_EPOCHS, *map(int, report_epochs)} if 1 <= e <= epochs))


def evaluated_epochs(report_epochs: Sequence[int], epochs: int) -> tuple[int, ...]:
    """The epochs a run of ``epochs`` epochs is evaluated at after training: the report epochs and
    :data:`RECOVERY_EPOCHS` (those it has)."""
    return tuple(sorted(e for e in {*map(int, report_epochs), *RECOVERY_EPOCHS} if 1 <= e <= epochs))


def has_report_episodes(run_dir: str | Path, epochs: Sequence[int], episodes: int) -> bool:
    """Whether ``run_dir`` holds the report evaluation of these epochs already (a study resumed after it)."""
    import pandas as pd

    path = Path(run_dir) / REPORT_FILE
    if not path.is_file():
        return False
    counts = pd.read_csv(path).groupby(["epoch", "kind"]).size()
    return all(counts.get((int(e), kind), 0) == episodes for e in epochs for kind in ("eval", "probe"))


def evaluate_report_epochs(run_dir: str | Path, env_id: str, epochs: Sequence[int], episodes: int,
                           max_steps: int) -> Path:
    """Play every report epoch's kept actor of ``run_dir`` (eval and probe episodes) and write ``REPORT_FILE``."""
    import gymnasium as gym
    import pandas as pd

    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.algos.bc import BCPolicy
    from surrol_data.algos.train_batched import actor_path
    from surrol_data.collect.rollout import rollout
    from surrol_data.evaluation.episode_rows import episode_row
    from surrol_data.evaluation.grip_probe import InducedFailure
    from surrol_data.evaluation.rollout import policy_threads

    run_dir = Path(run_dir)
    missing = [e for e in epochs if not actor_path(run_dir, e).is_file()]
    if missing:
        raise FileNotFoundError(f"{run_dir} keeps no actor of epoch(s) {missing} ({actor_path(run_dir, missing[0])}); "
                                "train it with the study, which keeps them")
    plain = gym.make(env_id, max_episode_steps=max_steps)
    probe = InducedFailure(gym.make(env_id, max_episode_steps=max_steps))
    rows = []
    try:
        for epoch in epochs:
            policy = BCPolicy.load(actor_path(run_dir, epoch))
            with policy_threads(policy):
                for k in range(episodes):
                    traj = rollout(plain, policy, REPORT_SEED_BASE + k)
                    rows.append({"epoch": epoch, "kind": "eval", "episode": k, "seed": REPORT_SEED_BASE + k,
                                 **episode_row(traj)})
                for k in range(episodes):
                    traj = rollout(probe, policy, PROBE_SEED_BASE + k)
                    rows.append({"epoch": epoch, "kind": "probe", "episode": k, "seed": PROBE_SEED_BASE + k,
                                 **episode_row(traj), "probed": probe.record.spent,
                                 "probe_from": probe.record.disabled_from, "probe_retries": probe.record.retries,
                                 "probe_prevented_grip": probe.record.prevented_grip})
    finally:
        plain.close()
        probe.close()
    path = run_dir / REPORT_FILE
    tmp = path.with_suffix(".tmp")
    pd.DataFrame(rows).to_csv(tmp, index=False)
    os.replace(tmp, path)
    return path

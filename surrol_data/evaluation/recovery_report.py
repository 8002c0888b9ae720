"""The study report's attempt, recovery and induced-failure tables, from each run's per-episode evaluation files.

Per demo source at a report epoch, pooled over its seeds (episodes from :func:`epoch_episodes`):

* attempts: attempts per episode, first-attempt success (of episodes with an attempt), and of the episodes whose
  first attempt failed, how many retried, how many of those then succeeded (recovered), and how many stalled
  (:mod:`surrol_data.datasets.attempts`);
* the probe: of the episodes whose first attempt the probe disabled (:mod:`surrol_data.evaluation.grip_probe`),
  how many retried and how many then succeeded.

Rates are pooled over episodes, with the percentile bootstrap 95 % interval of the pooled rate (episodes resampled;
:func:`~surrol_data.datasets.metrics.bootstrap_ci`) and the count it stands on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from surrol_data.datasets.attempts import Outcome
from surrol_data.datasets.metrics import bootstrap_ci
from surrol_data.evaluation.report import Column

REPORT_FILE = "report_episodes.csv"   # a run's report-epoch evaluation and probe episodes (study/report_eval.py)
EPISODES_FILE = "eval_episodes.csv"   # a run's per-epoch evaluation episodes at the report epochs (train_batched)
RETRIED = (Outcome.RECOVERED.value, Outcome.NOT_RECOVERED.value)
FIRST_FAILED = (*RETRIED, Outcome.STALL.value)


def _read(path: Path):
    import pandas as pd

    return pd.read_csv(path) if path.is_file() else None


def flags(values):
    """A True/False column of an episodes CSV as booleans (pandas reads it as bool, or as text where blanks mix in)."""
    return values.astype(str).str.lower() == "true"


def epoch_episodes(run_path: Path, epoch: int, kind: str = "eval"):
    """(episodes, where) of a run at ``epoch``: its report evaluation's rows of ``kind`` (``eval`` or ``probe``)
    where it has them (where = ``report``), else for ``eval`` the per-epoch evaluation's rows (``per-epoch``);
    (None, None) when it has neither."""
    report = _read(Path(run_path) / REPORT_FILE)
    if report is not None:
        rows = report[(report["epoch"] == epoch) & (report["kind"] == kind)]
        if len(rows):
            return rows, "report"
    if kind == "eval":
        per_epoch = _read(Path(run_path) / EPISODES_FILE)
        if per_epoch is not None and len(rows := per_epoch[per_epoch["epoch"] == epoch]):
            return rows, "per-epoch"
    return None, None


def rate_cell(hits, digits: int = 0) -> str:
    """``42 % [30, 55] (n=35)``: a pooled rate of 0/1 values with its bootstrap interval and count."""
    return _cell(hits, digits, 100.0, " %") + f" (n={len(list(hits))})"


def mean_cell(values, digits: int = 2) -> str:
    """``1.25 [1.00, 1.62]``: a mean with its bootstrap interval."""
    return _cell(values, digits, 1.0, "")


def _cell(values, digits: int, scale: float, unit: str) -> str:
    v = np.asarray(list(values), np.float64)
    if len(v) == 0:
        return "–"
    low, high = bootstrap_ci(v)
    interval = f" [{scale * low:.{digits}f}, {scale * high:.{digits}f}]" if np.isfinite(low) else ""
    return f"{scale * v.mean():.{digits}f}{unit}{interval}"


def _pooled(groups: Mapping[str, Sequence], epoch: int, kind: str, need: str):
    """{source: (episodes, seeds, where)} over the runs that have ``need`` among their columns, and the runs that
    lack it (``source/seed``)."""
    import pandas as pd

    pooled, missing = {}, []
    for source, runs in groups.items():
        frames, wheres = [], set()
        for run in runs:
            ep, where = epoch_episodes(run.path, epoch, kind)
            if ep is None or need not in ep.columns or ep[need].isna().all():
                missing.append(f"{source}/{run.seed}")
                continue
            frames.append(ep)
            wheres.add(where)
        if frames:
            pooled[source] = (pd.concat(frames, ignore_index=True), len(frames), "+".join(sorted(wheres)))
    return pooled, missing


def attempt_rows(groups: Mapping[str, Sequence], epoch: int) -> tuple[list[dict], list[str]]:
    """Per source at ``epoch``: the attempt table's row; and the runs without an attempt record there."""
    pooled, missing = _pooled(groups, epoch, "eval", "attempt_outcome")
    rows = []
    for source, (ep, seeds, where) in pooled.items():
        outcome = ep["attempt_outcome"].astype(str)
        tried = outcome != Outcome.NO_ATTEMPT.value
        failed = outcome[outcome.isin(FIRST_FAILED)]
        rows.append({"source": source, "epoch": str(epoch), "seeds": seeds, "episodes": f"{len(ep)} ({where})",
                     "attempts": mean_cell(ep["attempts"]),
                     "first_held": rate_cell(outcome[tried] == Outcome.FIRST_HELD.value),
                     "retried": rate_cell(failed.isin(RETRIED)),
                     "recovered": rate_cell(failed == Outcome.RECOVERED.value),
                     "stall": rate_cell(failed == Outcome.STALL.value),
                     "no_attempt": rate_cell(~tried)})
    return rows, missing


def probe_rows(groups: Mapping[str, Sequence], epoch: int) -> tuple[list[dict], list[str]]:
    """Per source at ``epoch``: the induced-failure table's row; and the runs without probe episodes there."""
    pooled, missing = _pooled(groups, epoch, "probe", "probed")
    rows = []
    for source, (ep, seeds, _) in pooled.items():
        probed = ep[flags(ep["probed"])]
        retried = probed["probe_retries"].astype(int) > 0
        success = flags(probed["final_success"])
        rows.append({"source": source, "epoch": str(epoch), "seeds": seeds, "episodes": len(ep),
                     "probed": len(probed), "retried": rate_cell(retried), "recovered": rate_cell(retried & success),
                     "stall": rate_cell(~retried)})
    return rows, missing


ATTEMPT_COLUMNS = (Column("source", "Source"), Column("epoch", "Epoch"), Column("seeds", "Seeds"),
                   Column("episodes", "Episodes"), Column("attempts", "Attempts / episode"),
                   Column("first_held", "First attempt held"), Column("retried", "After a failed first: retried"),
                   Column("recovered", "…retried and succeeded"), Column("stall", "…stalled (no retry)"),
                   Column("no_attempt", "No attempt"))
PROBE_COLUMNS = (Column("source", "Source"), Column("epoch", "Epoch"), Column("seeds", "Seeds"),
                 Column("episodes", "Episodes"), Column("probed", "First attempt disabled"),
                 Column("retried", "Retried"), Column("recovered", "Retried and succeeded"),
                 Column("stall", "Stalled (no retry)"))
ATTEMPT_DEFINITION = (
    "An attempt is a close of the jaw (command < 0) of at least two steps, with the measured jaw closing, that starts "
    "with the tool tip within 5 mm of the needle's grasp point (its mid-arc point, not its centre), or any close that "
    "held the needle; jaw flicker away from the needle is no attempt (nor is a miss away from its mid-arc point or a "
    "one-step close: policies here grip the needle up to 26 mm from that point, some by one-step closes, so such "
    "misses go uncounted; the probe below has neither blind spot). It failed when the needle was never held, or "
    "was lost before a 5 mm lift. An attempt after a failed one is a retry; an episode whose first attempt failed and "
    "that never retried stalled. First attempt held: of the episodes with an attempt; retried, recovered (retried and "
    "the episode ended in success) and stalled: of the episodes whose first attempt failed. Pooled over seeds: the "
    "rate, its bootstrap 95 % interval (episodes resampled) and the count it stands on. `report`: the report "
    "epoch's actor on fresh episodes; `per-epoch`: the training's own evaluation at that epoch.")
PROBE_DEFINITION = (
    "The paper's observation as an experiment: each report epoch's actor plays fresh episodes in which its first "
    "close near the needle (the jaw closing with a blade within 5 mm of the needle, anywhere on it, at the close's "
    "start or after its first step) cannot grip: the grip is off and the blades pass through the needle until "
    "the jaw opens; every later close grips as usual. Of the episodes with a close so disabled: how many "
    "retried (a later such close, or one that held the needle), how many retried and the episode ended in success, "
    "and how many stalled.")
# What a task's grasp holds, as its report names it.
OBJECT_NAMES = {"PegTransfer": "block", "GauzeRetrieve": "gauze"}


def object_name(task: str) -> str:
    return OBJECT_NAMES.get(task, "needle" if "Needle" in task else "object")


def attempt_definition(task: str = "NeedlePick") -> str:
    """The attempts table's definition: NeedlePick's with what was measured of its policies' grasps; another task's
    with its object, without NeedlePick's measurements."""
    if task == "NeedlePick":
        return ATTEMPT_DEFINITION
    o = object_name(task)
    rest = ATTEMPT_DEFINITION[ATTEMPT_DEFINITION.index("It failed when"):].replace("needle", o)
    return ("An attempt is a close of the jaw (command < 0) of at least two steps, with the measured jaw closing, that "
            f"starts with the tool tip within 5 mm of the {o}'s grasp point, or any close that held the {o}; jaw "
            f"flicker away from the {o} is no attempt (nor is a miss away from its grasp point, or a one-step close: "
            "the probe below has neither blind spot). " + rest)


def probe_definition(task: str = "NeedlePick") -> str:
    return PROBE_DEFINITION.replace("needle", object_name(task))

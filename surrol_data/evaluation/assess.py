"""Demonstration proficiency per operator and skill, with proficiency-based progression (PBP).

``assess_dataset(root)`` scores every episode of a dataset with the proficiency metrics (smoothness from the
episode's device trace where the haptic session saved one), then

* summarises per operator (grouped by source and skill) and per skill;
* derives the **expert benchmark** as the mean over the expert operators' successful episodes of steps to
  complete, path length and errors (failed grasps + drops), as proficiency-based progression does (Gallagher
  and colleagues: the benchmark is the experienced operators' mean performance);
* in a dataset of intervention sessions, counts per operator the takeovers from the policy and the share of frames
  the operator drove (:mod:`surrol_data.datasets.interventions`);
* marks each episode that meets the benchmark (success, and no worse than the benchmark on every metric) and
  each operator as *proficient* from the first of two consecutive episodes that meet it.

``write_assessment(result, out)`` writes ``assessment.md`` and ``assessment.png`` (per-operator distributions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from surrol_data.datasets.attempts import trajectory_attempts
from surrol_data.datasets.interventions import trajectory_interventions
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.metrics import recorded_device_trace, trajectory_proficiency
from surrol_data.evaluation.report import Column, metrics_table_markdown

BENCHMARK_METRICS = ("steps_to_success", "path_length_cm", "errors")
SKILL_COLOURS = {"expert": "#55a868", "novice": "#dd8452", "scripted": "#4c72b0", "unknown": "#8c8c8c"}
ASSESS_COLUMNS = (
    Column("group", "Operator / group"), Column("skill", "Skill"), Column("episodes", "Episodes"),
    Column("success_rate", "Success (any step)", lambda v: f"{100 * v:.0f} %"),
    Column("steps_to_success", "Steps to complete", lambda v: f"{v:.1f}"),
    Column("path_length_cm", "Path (cm)", lambda v: f"{v:.1f}"),
    Column("sparc", "SPARC", lambda v: f"{v:.2f}"),
    Column("log_dimensionless_jerk", "LDLJ", lambda v: f"{v:.1f}"),
    Column("idle_time_s", "Idle (s)", lambda v: f"{v:.1f}"),
    Column("clutch_uses", "Clutch", lambda v: f"{v:.1f}"),
    Column("jaw_closures", "Jaw closures", lambda v: f"{v:.1f}"),
    Column("errors", "Errors", lambda v: f"{v:.2f}"),
    Column("meets_benchmark", "Meets benchmark", lambda v: f"{100 * v:.0f} %"),
    Column("proficient_at", "Proficient at trial", str),
)
# Added where the dataset holds intervention sessions: how much the operator had to step in.
INTERVENTION_COLUMNS = (
    Column("takeovers", "Takeovers / ep", lambda v: f"{v:.1f}"),
    Column("intervention_share", "Operator frames", lambda v: f"{100 * v:.0f} %"),
)


@dataclass
class Assessment:
    dataset: Path
    episodes: pd.DataFrame          # one row per episode: provenance keys + metrics + meets_benchmark
    benchmark: dict[str, float]     # empty when the dataset has no successful expert episode
    operators: pd.DataFrame         # one row per (source, skill, operator)
    skills: pd.DataFrame            # one row per skill


def _errors(row: pd.Series) -> float:
    known = [v for v in (row["failed_grasps"], row["drops"]) if np.isfinite(v)]
    return float(sum(known)) if known else math.nan


def score_episodes(reader: DatasetReader) -> pd.DataFrame:
    rows = []
    for meta, traj in zip(reader.episodes.to_dict("records"), reader.trajectories()):
        prof = trajectory_proficiency(traj, device_trace=recorded_device_trace(reader.root, int(meta["episode_index"])))
        counts = trajectory_interventions(traj)
        attempts = trajectory_attempts(traj)
        rows.append({"episode_index": int(meta["episode_index"]), "source": meta.get("source", "unknown"),
                     "skill": meta.get("skill", "unknown"), "operator_id": meta.get("operator_id", "") or "–",
                     **prof.as_dict(),
                     # grasp attempts, failed attempts and retries (datasets/attempts.py), where the task has them
                     **({} if attempts is None else attempts.as_row()),
                     **({} if counts is None else {"takeovers": counts.takeovers,
                                                   "intervention_frames": counts.intervention_frames,
                                                   "time_to_takeover_s": counts.time_to_takeover_s})})
    frame = pd.DataFrame(rows)
    if len(frame):
        frame["errors"] = frame.apply(_errors, axis=1)
        frame.loc[~frame["success"], "steps_to_success"] = np.nan
    return frame


def expert_benchmark(episodes: pd.DataFrame) -> dict[str, float]:
    """Mean of the expert operators' successful episodes on each benchmark metric (NaN-aware); {} if none."""
    experts = episodes[(episodes["skill"] == "expert") & episodes["success"]] if len(episodes) else episodes
    if not len(experts):
        return {}
    return {m: float(np.nanmean(experts[m])) if experts[m].notna().any() else math.nan for m in BENCHMARK_METRICS}


def meets(row: pd.Series, benchmark: dict[str, float]) -> bool:
    if not benchmark or not row["success"]:
        return False
    return all(not (np.isfinite(benchmark[m]) and np.isfinite(row[m])) or row[m] <= benchmark[m]
               for m in BENCHMARK_METRICS)


def proficient_at(flags: list[bool]) -> int:
    """1-based trial at which two consecutive trials first met the benchmark (the first of the pair); 0 if never."""
    for i in range(len(flags) - 1):
        if flags[i] and flags[i + 1]:
            return i + 1
    return 0


def _summary(group: pd.DataFrame) -> dict:
    ok = group[group["success"]]

    def mean(frame, col):
        v = frame[col].astype(float)
        return float(v.mean()) if v.notna().any() else math.nan

    return {"episodes": len(group), "success_rate": float(group["success"].mean()),
            "steps_to_success": mean(ok, "steps_to_success"), "path_length_cm": mean(ok, "path_length_cm"),
            "sparc": mean(ok, "sparc"), "log_dimensionless_jerk": mean(ok, "log_dimensionless_jerk"),
            "idle_time_s": mean(group, "idle_time_s"), "clutch_uses": mean(group, "clutch_uses"),
            "jaw_closures": mean(group, "jaw_closures"), "errors": mean(group, "errors"),
            "meets_benchmark": float(group["meets_benchmark"].mean()),
            **({"takeovers": mean(group, "takeovers"),
                "intervention_share": float(group["intervention_frames"].sum() / group["steps"].sum())}
               if "takeovers" in group and group["takeovers"].notna().any() else {})}


def assess_dataset(root: str | Path) -> Assessment:
    reader = DatasetReader(root)
    episodes = score_episodes(reader)
    if not len(episodes):
        raise ValueError(f"{root}: the dataset has no episodes to assess; record some with `surrol-data collect`")
    benchmark = expert_benchmark(episodes)
    episodes["meets_benchmark"] = [meets(r, benchmark) for _, r in episodes.iterrows()]
    operators = []
    for (source, skill, operator), group in episodes.groupby(["source", "skill", "operator_id"], sort=True):
        group = group.sort_values("episode_index")
        at = proficient_at(list(group["meets_benchmark"]))
        operators.append({"group": f"{operator} ({source})", "skill": skill, **_summary(group),
                          "proficient_at": str(at) if at else "–"})
    skills = [{"group": f"all {skill}", "skill": skill, **_summary(g), "proficient_at": ""}
              for skill, g in episodes.groupby("skill", sort=True)]
    return Assessment(Path(root), episodes, benchmark, pd.DataFrame(operators), pd.DataFrame(skills))


def assessment_title(result: Assessment) -> str:
    return f"Demonstration proficiency: {result.dataset.name}"


def assessment_columns(result: Assessment) -> tuple[Column, ...]:
    """The table's columns: :data:`ASSESS_COLUMNS`, and :data:`INTERVENTION_COLUMNS` for intervention sessions."""
    has = "takeovers" in result.episodes and result.episodes["takeovers"].notna().any()
    return ASSESS_COLUMNS + INTERVENTION_COLUMNS if has else ASSESS_COLUMNS


def assessment_rows(result: Assessment) -> list[dict]:
    """The table's rows: one per operator, then one per skill (columns :data:`ASSESS_COLUMNS`)."""
    return result.operators.to_dict("records") + result.skills.to_dict("records")


def assessment_notes(result: Assessment) -> str:
    """What follows the table (markdown): the expert benchmark and how the columns are measured."""
    if result.benchmark:
        b = result.benchmark
        bench = (f"Expert benchmark (mean of the expert operators' successful episodes): "
                 f"{b['steps_to_success']:.1f} steps, {b['path_length_cm']:.1f} cm, "
                 + (f"{b['errors']:.2f} errors. " if np.isfinite(b["errors"]) else "errors not recorded. ")
                 + "An episode meets it when it succeeds and is no worse on each; an operator is proficient from the "
                 "first of two consecutive episodes that meet it.")
    else:
        bench = "No successful expert episode in this dataset: no benchmark, so no proficiency-based progression."
    return (f"{bench}\n\nSuccess is any-step success; steps, path and smoothness are means over successful episodes; "
            "errors = failed grasps + drops; SPARC and LDLJ: higher is smoother, from the device trace where there is "
            "one.\n")


def assessment_markdown(result: Assessment) -> str:
    table = metrics_table_markdown(assessment_rows(result), assessment_columns(result))
    return (f"# {assessment_title(result)}\n\n{table}\n"
            f"{assessment_notes(result)}")


def plot_assessment(path: str | Path, result: Assessment) -> Path:
    """Per-operator distributions (dots = episodes) of steps to complete, path length and SPARC."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = result.episodes[result.episodes["success"]]
    groups = list(result.operators["group"])
    keys = [(g.split(" (")[0], g.split(" (")[1].rstrip(")")) for g in groups]
    fig, axes = plt.subplots(1, 3, figsize=(12, 0.5 * len(groups) + 2.0), sharey=True)
    for ax, (metric, label) in zip(axes, (("steps_to_success", "steps to complete"), ("path_length_cm", "path (cm)"),
                                          ("sparc", "SPARC (higher = smoother)"))):
        for y, ((operator, source), skill) in enumerate(zip(keys, result.operators["skill"])):
            values = ep[(ep["operator_id"] == operator) & (ep["source"] == source)][metric].astype(float).dropna()
            jitter = np.random.default_rng(y).uniform(-0.15, 0.15, len(values))
            ax.scatter(values, y + jitter, s=12, alpha=0.7, color=SKILL_COLOURS.get(skill, "#8c8c8c"))
            if len(values):
                ax.plot([values.mean()] * 2, [y - 0.3, y + 0.3], color="black", linewidth=1.5)
        bench = result.benchmark.get(metric)
        if bench is not None and np.isfinite(bench):
            ax.axvline(bench, color="#55a868", linestyle="--", linewidth=1, label="expert benchmark")
            ax.legend(loc="lower right", fontsize=8)
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(range(len(groups)), groups)
    fig.suptitle(f"{result.dataset.name}: successful episodes per operator (bar = mean)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_assessment(result: Assessment, out: str | Path) -> dict[str, Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figure = plot_assessment(out / "assessment.png", result)
    md = out / "assessment.md"
    md.write_text(assessment_markdown(result) + f"\n![per operator]({figure.name})\n")
    result.episodes.to_csv(out / "episodes.csv", index=False)
    return {"markdown": md, "figure": figure, "episodes": out / "episodes.csv"}

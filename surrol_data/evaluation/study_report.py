"""The demo-source study report (the paper's Table I protocol): learning curves and the Table I layout.

``write_study_report(run_dirs, out)`` reads training runs (folders with ``metrics.jsonl`` and ``config.json``,
found recursively under the paths given), groups them by demo source, and writes into ``out``:

* ``learning_curves.png``: evaluation success per epoch, mean over seeds with a ±1 std band, one colour per
  demo source (and steps to complete, economy of motion below it);
* ``report.md`` and ``report.html`` (self-contained: figures embedded): the Table I layout (rows success /
  steps to complete under both conventions / economy of motion; columns the demo sources at two epochs), the
  paper's figures beside ours, the attempts and recovery of each source's policies, the induced-failure probe,
  an optional demo-quality table, and what made the numbers (runs, seeds, commands, versions, commit).

Success is the evaluation's final-step success (the paper's and DEX's convention); "economy of motion" is the
mean over successful episodes, as the training loop logs it; "steps to complete" is given twice, labelled: over
successful episodes only, and with every failed episode counted at the horizon. At the report epochs the figures
come from each run's ``report_episodes.csv`` (:data:`REPORT_FILE`: the kept actor of that epoch on fresh episodes,
written by :mod:`surrol_data.study.report_eval`) where the run has one, else from the per-epoch evaluation
(``metrics.jsonl``, and ``eval_episodes.csv`` for the horizon convention); the report says which.
"""

from __future__ import annotations

import base64
import html
import json
import math
import platform
import subprocess
from collections import defaultdict
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from surrol_data.datasets.metrics import Estimate, estimate
from surrol_data.evaluation.recovery_report import (ATTEMPT_COLUMNS, PROBE_COLUMNS, REPORT_FILE, attempt_definition,
                                                     attempt_rows, epoch_episodes, flags, probe_definition,
                                                     probe_rows)
from surrol_data.evaluation.report import Column, metrics_table_markdown

SOURCES_ORDER = ("script", "novice", "expert")
SOURCE_COLOURS = {"script": "#4c72b0", "novice": "#dd8452", "expert": "#55a868", "none": "#7f7f7f"}
OTHER_COLOURS = ("#8172b3", "#c44e52", "#937860", "#da8bc3", "#8c8c8c")
# The paper's Table I (NeedlePick, DDPG+BC+HER, 100 demos per source): mean ± std at 50 and 100 epochs. It does
# not say how failed episodes enter "steps to complete": its figures stand beside both of our conventions.
PAPER_TABLE1 = {
    50: {"success_rate": {"expert": (89.7, 6.4), "novice": (66.3, 12.7), "script": (43.2, 21.9)},
         "steps_to_complete": {"expert": (39.2, 14.5), "novice": (59.5, 17.1), "script": (101.8, 27.1)},
         "economy_of_motion_cm": {"expert": (12.2, 1.3), "novice": (14.2, 3.1), "script": (15.0, 2.5)}},
    100: {"success_rate": {"expert": (99.3, 0.1), "novice": (86.7, 2.4), "script": (93.2, 6.9)},
          "steps_to_complete": {"expert": (15.0, 5.5), "novice": (21.4, 5.9), "script": (24.0, 10.4)},
          "economy_of_motion_cm": {"expert": (11.6, 1.1), "novice": (12.6, 2.9), "script": (13.5, 1.6)}},
}
PAPER_TABLE1_KEY = {"steps_to_complete_horizon": "steps_to_complete"}   # the paper's one steps row, beside both
# (key, label, scale, digits): the learning curves' metrics, each logged every epoch ...
CURVE_METRICS = (("success_rate", "Success rate (%)", 100.0, 1),
                 ("steps_to_complete", "Steps to complete (successes only)", 1.0, 1),
                 ("economy_of_motion_cm", "Economy of motion (cm)", 1.0, 1))
# ... and Table I's, which adds steps with every failure counted at the horizon
TABLE_METRICS = (CURVE_METRICS[:2] + (("steps_to_complete_horizon", "Steps to complete (failures at the horizon)",
                                       1.0, 1),) + CURVE_METRICS[2:])
CURVES_FILE = "learning_curves.png"


class StudyReportError(ValueError):
    """What was wrong with the runs given to the report, and what to do."""


@dataclass(frozen=True)
class Run:
    path: Path
    task: str
    algo: str
    source: str
    seed: int
    rows: list[dict]
    config: dict
    record: dict | None = None      # run.json of a study run: code identity, versions, demo hash, times

    def at_epoch(self, epoch: int) -> dict | None:
        for row in self.rows:
            if int(row["epoch"]) == epoch:
                return row
        return None

    @property
    def epochs(self) -> int:
        return max((int(r["epoch"]) for r in self.rows), default=0)


def _read_run(path: Path) -> Run:
    rows = [json.loads(line) for line in (path / "metrics.jsonl").read_text().splitlines() if line.strip()]
    config_path = path / "config.json"
    if not config_path.is_file():
        raise StudyReportError(f"{path}: metrics.jsonl without config.json; is it a complete training run folder?")
    config = json.loads(config_path.read_text())
    env_id = str(config.get("env_id", "?"))
    task = env_id.split("/")[-1].rsplit("-v", 1)[0]
    record_path = path / "run.json"
    record = json.loads(record_path.read_text()) if record_path.is_file() else None
    algo = (record or {}).get("algo") or config.get("algo_name", config.get("learner", "?"))
    return Run(path=path, task=task, algo=str(algo),
               source=demo_source(config.get("demos") or {}), seed=int(config.get("seed", 0)), rows=rows,
               config=config, record=record)


def demo_source(demos: dict) -> str:
    """The demo source of a run from its demo spec: the skill it selected (expert, novice), script, or none."""
    if demos.get("name"):
        return str(demos["name"])
    if not demos.get("path"):
        return "none"
    where = demos.get("where") or {}
    if where.get("skill") in ("expert", "novice"):
        return str(where["skill"])
    if where.get("source") == "script" or where.get("skill") == "scripted":
        return "script"
    return Path(str(demos["path"])).name


def discover_runs(paths: Sequence[str | Path]) -> list[Run]:
    """Every run folder (one with ``metrics.jsonl``) at or below the given paths, sorted by source and seed."""
    found: dict[Path, Run] = {}
    for p in map(Path, paths):
        if not p.exists():
            raise StudyReportError(f"{p} does not exist; give run folders or folders that contain them (e.g. runs/)")
        candidates = [p] if (p / "metrics.jsonl").is_file() else sorted(m.parent for m in p.rglob("metrics.jsonl"))
        for c in candidates:
            found.setdefault(c.resolve(), _read_run(c))
    if not found:
        raise StudyReportError(f"no training runs (folders with metrics.jsonl) under {[str(p) for p in paths]}; "
                               "train first, e.g. `surrol-data train experiment=table1_quick`")
    order = {s: i for i, s in enumerate(SOURCES_ORDER)}
    return sorted(found.values(), key=lambda r: (order.get(r.source, len(order)), r.source, r.seed, str(r.path)))


def by_source(runs: Sequence[Run]) -> dict[str, list[Run]]:
    groups: dict[str, list[Run]] = defaultdict(list)
    for run in runs:
        groups[run.source].append(run)
    return dict(groups)


def report_epochs(runs: Sequence[Run], requested: Sequence[int] | None = None) -> tuple[int, ...]:
    """The two epochs of the table: the paper's 50 and 100 when the runs are that long, else half and all."""
    if requested:
        return tuple(int(e) for e in requested)
    last = min(r.epochs for r in runs)
    return (50, 100) if last >= 100 else tuple(sorted({max(1, last // 2), last}))


def epoch_scores(run: Run, epoch: int) -> tuple[dict, str | None]:
    """One run's Table I figures at ``epoch`` and where they come from: its report evaluation (``report``: the kept
    actor on fresh episodes), else the per-epoch evaluation (``metrics.jsonl``; steps with failures at the horizon
    from ``eval_episodes.csv`` where it has the epoch); ({}, None) when it has neither."""
    episodes, where = epoch_episodes(run.path, epoch)
    horizon = float((run.config.get("schedule") or {}).get("max_episode_steps", math.nan))
    scores = {}
    if episodes is not None:
        success = flags(episodes["success"])
        steps = episodes["steps_to_success"].astype(float)
        scores["steps_to_complete_horizon"] = float(np.where(success, steps, horizon).mean())
        if where == "report":
            final = flags(episodes["final_success"])
            ok = episodes[success]
            scores.update({"success_rate": float(final.mean()),
                           "steps_to_complete": float(steps[success].mean()) if len(ok) else math.nan,
                           "economy_of_motion_cm": float(ok["path_length_cm"].mean()) if len(ok) else math.nan})
            return scores, "report"
    row = run.at_epoch(epoch)
    if row is None:
        return scores, None
    scores.update({k: row.get(k, math.nan) for k in ("success_rate", "steps_to_complete", "economy_of_motion_cm")})
    return scores, "per-epoch"


def table1_estimates(runs: Sequence[Run], epochs: Sequence[int]) -> dict[int, dict[str, dict[str, Estimate]]]:
    """{epoch: {metric: {source: Estimate over seeds}}}; a seed contributes only where it has that epoch."""
    out: dict[int, dict[str, dict[str, Estimate]]] = {}
    for epoch in epochs:
        out[epoch] = {metric: {} for metric, *_ in TABLE_METRICS}
        for source, group in by_source(runs).items():
            scores = [epoch_scores(r, epoch)[0] for r in group]
            for metric, *_ in TABLE_METRICS:
                out[epoch][metric][source] = estimate([sc.get(metric, math.nan) for sc in scores if sc])
    return out


def table1_sources_note(runs: Sequence[Run], epochs: Sequence[int]) -> str:
    """What Table I's cells at each epoch stand on: how many runs' report evaluations (and episodes each), how many
    runs' per-epoch evaluations."""
    parts = []
    for epoch in epochs:
        report, per_epoch = [], []
        for run in runs:
            _, where = epoch_scores(run, epoch)
            if where == "report":
                report.append(len(epoch_episodes(run.path, epoch)[0]))
            elif where == "per-epoch":
                per_epoch.append(f"{run.source}/{run.seed}")
        text = f"epoch {epoch}: "
        if len(per_epoch) == len(runs):
            per_epoch = [f"all {len(runs)} runs"]
        if report:
            text += (f"{len(report)} run(s) on their kept actor's evaluation of "
                     f"{'/'.join(map(str, sorted(set(report))))} fresh episodes")
        if per_epoch:
            evals = sorted({int((r.config.get('schedule') or {}).get('eval_episodes', 0)) for r in runs
                            if epoch_scores(r, epoch)[1] == "per-epoch"})
            text += (("; " if report else "") + f"the per-epoch evaluation ({'/'.join(map(str, evals))} episodes) "
                     f"of {', '.join(per_epoch)} (no {REPORT_FILE})")
        parts.append(text)
    return "Table I stands on " + "; ".join(parts) + "."


def _paper_cell(epoch: int, metric: str, source: str, scale: float) -> str:
    value = PAPER_TABLE1.get(epoch, {}).get(PAPER_TABLE1_KEY.get(metric, metric), {}).get(source)
    if value is None:
        return "–"
    mean, std = value
    return f"{mean:.1f}" if std is None else f"{mean:.1f} ± {std:.1f}"


def _with_ci(est: Estimate, digits: int, scale: float) -> str:
    """``mean ± std [low, high]``: the bootstrap 95 % interval of the mean over seeds where there are two or more."""
    text = est.format(digits, scale)
    if est.n >= 2 and math.isfinite(est.ci_low):
        text += f" [{est.ci_low * scale:.{digits}f}, {est.ci_high * scale:.{digits}f}]"
    return text


def recovery_rows(runs: Sequence[Run], epoch: int) -> list[dict]:
    """The jaw-flicker count of runs evaluated before the attempt measure (their ``eval_episodes.csv`` has
    ``first_grasp_failed``): per source at ``epoch``, episodes whose first jaw closure held nothing and how many
    still ended in success, pooled over seeds. The report no longer shows it (:func:`recovery_sections` counts
    attempts instead); the README's summary of the committed study quotes it."""
    import pandas as pd

    rows = []
    for source, group in by_source(runs).items():
        frames = []
        for run in group:
            path = run.path / "eval_episodes.csv"
            if path.is_file():
                ep = pd.read_csv(path)
                if "first_grasp_failed" in ep.columns:
                    frames.append(ep[ep["epoch"] == epoch])
        if not frames:
            continue
        ep = pd.concat(frames)
        first_failed = flags(ep["first_grasp_failed"])
        recovered = flags(ep["recovered"])
        n_failed = int(first_failed.sum())
        rows.append({"source": source, "seeds": len(frames), "episodes": len(ep),
                     "closed_jaw": int(ep["first_grasp_failed"].notna().sum()), "first_failed": n_failed,
                     "recovered": int(recovered.sum()),
                     "rate": f"{100 * recovered.sum() / n_failed:.0f} %" if n_failed else "–",
                     "failed_grasps": float(ep["failed_grasps"].mean())})
    return rows


STEPS_CONVENTIONS = ("Steps to complete is given twice: over the successful episodes only (what the training loop "
                     "logs), and with every failed episode counted at the horizon. The paper does not say which it "
                     "used; its figures stand beside both (its 101.8 ± 27.1 steps at 43 % success would, with "
                     "failures at its 150-step horizon, mean successes of about 38 steps).")


def _run_list(missing: Mapping[str, Sequence[str]], n_runs: int, n_epochs: int) -> str:
    """``all 12 runs`` when every run lacks it at every epoch, else each run with its epochs."""
    if len(missing) == n_runs and all(len(e) == n_epochs for e in missing.values()):
        return f"all {n_runs} runs ({', '.join(missing)})"
    return ", ".join(f"{name} (epoch {', '.join(e)})" for name, e in missing.items())


def recovery_sections(runs: Sequence[Run], epochs: Sequence[int]) -> list[str]:
    """The attempts-and-recovery and the induced-failure sections, each saying which runs it lacks and why."""
    groups = by_source(runs)
    task = runs[0].task if runs else "NeedlePick"
    out = []
    for title, build, columns, definition, lack in (
            ("Attempts and recovery", attempt_rows, ATTEMPT_COLUMNS, attempt_definition(task),
             "no per-episode attempt record at that epoch (their evaluation files predate the attempt measure, or "
             "the task has no grasp record)"),
            ("Induced failure: the first attempt made to fail", probe_rows, PROBE_COLUMNS, probe_definition(task),
             f"no probe episodes ({REPORT_FILE}, written by the study after training since the probe was added)")):
        rows, missing = [], {}
        for epoch in epochs:
            found, lacking = build(groups, epoch)
            rows += found
            for name in lacking:
                missing.setdefault(name, []).append(str(epoch))
        out.append(f"\n## {title}\n")
        if rows:
            out.append(metrics_table_markdown(rows, columns) + "\n\n" + definition + "\n")
        else:
            out.append(f"No run has it. {definition}\n")
        if missing:
            out.append(f"Not in the table: {_run_list(missing, len(runs), len(epochs))}: {lack}.\n")
    return out


def table1_markdown(estimates: Mapping[int, Mapping[str, Mapping[str, Estimate]]], sources: Sequence[str]) -> str:
    """Rows: metric × epoch; columns: ours and the paper's for each demo source."""
    columns = [Column("metric", "Metric"), Column("epoch", "Epoch")]
    for s in sources:
        columns += [Column(f"ours_{s}", f"{s} (ours)"), Column(f"paper_{s}", f"{s} (paper)")]
    rows = []
    for metric, label, scale, digits in TABLE_METRICS:
        for epoch, per_metric in estimates.items():
            row = {"metric": label, "epoch": str(epoch)}
            for s in sources:
                est = per_metric[metric].get(s)
                row[f"ours_{s}"] = _with_ci(est, digits, scale) if est else "–"
                row[f"paper_{s}"] = _paper_cell(epoch, metric, s, scale)
            rows.append(row)
    return metrics_table_markdown(rows, columns)


def plot_learning_curves(path: str | Path, runs: Sequence[Run], title: str | None = None) -> Path:
    """Success, steps to complete and economy per epoch: mean over seeds with a ±1 std band per source."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(3, 1, figsize=(7.5, 9.0), sharex=True)
    for k, (source, group) in enumerate(by_source(runs).items()):
        colour = SOURCE_COLOURS.get(source, OTHER_COLOURS[k % len(OTHER_COLOURS)])
        epochs = sorted({int(r["epoch"]) for run in group for r in run.rows})
        for ax, (metric, label, scale, _) in zip(axes, CURVE_METRICS):
            values = np.full((len(group), len(epochs)), np.nan)
            for i, run in enumerate(group):
                for j, e in enumerate(epochs):
                    row = run.at_epoch(e)
                    v = row.get(metric) if row else None
                    values[i, j] = np.nan if v is None else float(v) * scale
            with np.errstate(invalid="ignore"), _quiet_nan_warnings():
                mean = np.nanmean(values, axis=0)
                std = np.nanstd(values, axis=0)
            ax.plot(epochs, mean, color=colour, marker="o", markersize=3, label=f"{source} ({len(group)} seed{'' if len(group) == 1 else 's'})")
            ax.fill_between(epochs, mean - std, mean + std, color=colour, alpha=0.2, linewidth=0)
            ax.set_ylabel(label)
    axes[0].set_ylim(-2, 102)
    axes[0].legend(loc="lower right")
    axes[-1].set_xlabel("epoch")
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


class _quiet_nan_warnings:
    """nanmean of an all-nan column (a metric no seed has at that epoch) is nan, as wanted: no warning."""

    def __enter__(self):
        import warnings

        self._ctx = warnings.catch_warnings()
        self._ctx.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc):
        return self._ctx.__exit__(*exc)


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("surrol-data", "torch", "lerobot", "pybullet", "gymnasium", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10,
                              cwd=Path(__file__).resolve().parent).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _provenance_markdown(runs: Sequence[Run], command: str | None, report_dir: Path) -> str:
    lines = ["| source | seed | epochs | commit | CPU time | wall time | run folder |", "|:---|---:|---:|:---|---:|---:|:---|"]
    for run in runs:
        rec = run.record or {}
        code, when = rec.get("code", {}), rec.get("time", {})
        hours = lambda s: f"{s / 3600:.2f} h" if s else "–"  # noqa: E731
        lines.append(f"| {run.source} | {run.seed} | {run.epochs} | {code.get('commit', '–')[:10]} | "
                     f"{hours(when.get('cpu_s'))} | {hours(when.get('wall_s'))} | `{_shown_path(run.path, report_dir)}` |")
    package_versions = ", ".join(f"{k} {v}" for k, v in versions().items())
    cmd = f"\n\nReport command: `{command}`" if command else ""
    tasks = sorted({r.task for r in runs})
    algos = sorted({r.algo for r in runs})
    return ("\n".join(lines) + f"\n\nTask: {', '.join(tasks)}; algorithm: {', '.join(algos)}. Versions: {package_versions}; "
            f"commit {_git_commit()}.{cmd}\n")


def check_runs_code(runs: Sequence[Run], code_checks: Sequence = ()) -> None:
    """Refuse runs whose recorded code identity (run.json) differs in meaning (see
    :mod:`surrol_data.evaluation.code_identity`); runs without a record (plain training runs) are not checked."""
    from surrol_data.evaluation.code_identity import CodeIdentity, CodeIdentityError, check_same_code

    identities = {f"run {r.source}/{r.seed} ({r.path})": CodeIdentity.from_dict(r.record["code"])
                  for r in runs if r.record and "code" in r.record}
    try:
        check_same_code(identities, list(code_checks))
    except CodeIdentityError as e:
        raise StudyReportError(str(e)) from None


def _shown_path(path: Path, report_dir: Path) -> str:
    """A run folder as a reader of the report finds it: relative to the report when below it."""
    try:
        return path.resolve().relative_to(report_dir.resolve()).as_posix()
    except ValueError:
        return str(path)


def write_study_report(run_paths: Sequence[str | Path], out: str | Path, *, epochs: Sequence[int] | None = None,
                       demo_table_markdown: str | None = None, notes: str | None = None,
                       command: str | None = None, title: str = "Does who demonstrated matter?",
                       expected_runs: Sequence[str] | None = None, code_checks: Sequence = (),
                       recovery_epochs: Sequence[int] | None = None,
                       figures: Callable[[Sequence[Run], Path], list[str]] | None = None) -> dict[str, Path]:
    """Write report.md, report.html and learning_curves.png into ``out``; returns their paths.

    ``expected_runs`` (``source/seed`` names): the study's runs; a report standing on fewer is marked partial and
    names the missing ones. Runs that recorded a code identity must mean the same code (``code_checks`` adds the
    study's before/after checks), else :class:`StudyReportError`. ``recovery_epochs``: the epochs of the attempts and
    induced-failure tables (default: Table I's), those the runs reached. ``figures``: called with the runs and
    ``out``, draws more figures there and returns their sections (the study's retry frames)."""
    runs = discover_runs(run_paths)
    check_runs_code(runs, code_checks)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    at = report_epochs(runs, epochs)
    sources = list(by_source(runs))
    estimates = table1_estimates(runs, at)
    curves = plot_learning_curves(out / CURVES_FILE, runs, title=f"{runs[0].task}: evaluation per epoch")
    have = [f"{r.source}/{r.seed}" for r in runs]
    missing = [name for name in (expected_runs or []) if name not in have]
    partial = ""
    if missing:
        title += " (partial)"
        partial = (f"**Partial study: this report stands on {len(have)} of the study's {len(expected_runs)} runs** "
                   f"({', '.join(have)}). Missing: {', '.join(missing)}. Every figure below changes as runs are "
                   "added.\n")
    sections = [
        f"# {title}\n",
        *([partial] if partial else []),
        "Policies trained on demonstrations of each source, evaluated every epoch on unseen seeds. "
        f"Table I layout: ours (mean ± std over seeds, then the bootstrap 95 % interval of the mean) beside the "
        f"paper's, at epochs {', '.join(map(str, at))}.\n",
        "## Table I\n", table1_markdown(estimates, sources),
        "\n" + table1_sources_note(runs, at) + " " + STEPS_CONVENTIONS + "\n",
        f"\n## Learning curves\n\n![learning curves]({CURVES_FILE})\n",
        *recovery_sections(runs, at if recovery_epochs is None else
                           [e for e in recovery_epochs if any(r.epochs >= e for r in runs)]),
        *(figures(runs, out) if figures else []),
    ]
    if demo_table_markdown:
        sections += ["\n## Demonstrations\n", demo_table_markdown]
    if notes:
        sections += ["\n## Notes\n", notes.strip() + "\n"]
    sections += ["\n## What made these numbers\n", _provenance_markdown(runs, command, out)]
    markdown = "\n".join(sections)
    md_path = out / "report.md"
    md_path.write_text(markdown)
    html_path = out / "report.html"
    html_path.write_text(markdown_to_html(markdown, out, title))
    return {"markdown": md_path, "html": html_path, "curves": curves}


# ------------------------------------------------------------------------------------------------ HTML
_CSS = ("body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
        "table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #ccc;padding:4px 8px}"
        "th{background:#f2f2f2}td.num{text-align:right}img{max-width:100%}code{background:#f6f6f6}")


def _inline(text: str, folder: Path) -> str:
    """Escape, then the little inline markdown the report uses: `code`, <br>, ![alt](file.png)."""
    import re

    parts = re.split(r"(!\[[^\]]*\]\([^)]+\)|`[^`]*`|<br>)", text)
    out = []
    for part in parts:
        image = re.fullmatch(r"!\[([^\]]*)\]\(([^)]+)\)", part)
        if image:
            data = base64.b64encode((folder / image.group(2)).read_bytes()).decode("ascii")
            out.append(f'<img alt="{html.escape(image.group(1))}" src="data:image/png;base64,{data}">')
        elif part.startswith("`") and part.endswith("`") and len(part) >= 2:
            out.append(f"<code>{html.escape(part[1:-1])}</code>")
        elif part == "<br>":
            out.append("<br>")
        else:
            out.append(html.escape(part).replace("\\|", "|"))
    return "".join(out)


def markdown_to_html(markdown: str, folder: Path, title: str) -> str:
    """The report's markdown (headings, paragraphs, pipe tables, images) as one self-contained HTML page."""
    body: list[str] = []
    lines = markdown.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            body.append(f"<h{level}>{_inline(line[level:].strip(), folder)}</h{level}>")
        elif line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].startswith("|"):
                block.append(lines[i])
                i += 1
            body.append(_table_html(block, folder))
            continue
        elif line.strip():
            body.append(f"<p>{_inline(line, folder)}</p>")
        i += 1
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def _cells(row: str) -> list[str]:
    import re

    return [c.strip() for c in re.split(r"(?<!\\)\|", row.strip().strip("|"))]


def _table_html(block: list[str], folder: Path) -> str:
    head, rows = _cells(block[0]), [_cells(r) for r in block[2:]]
    out = ["<table><thead><tr>" + "".join(f"<th>{_inline(h, folder)}</th>" for h in head) + "</tr></thead><tbody>"]
    for row in rows:
        out.append("<tr>" + "".join(f'<td class="num">{_inline(c, folder)}</td>' if i else f"<td>{_inline(c, folder)}</td>"
                                    for i, c in enumerate(row)) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)

"""Markdown reports: a metrics table per policy / demo source, a comparison figure and links to recordings.

Three pieces, reusable on their own (e.g. for the Table I protocol: success / steps / economy of motion per
demo source and skill):

* :func:`metrics_table_markdown` renders rows of dicts (one per source) as a markdown table, columns chosen
  by :class:`Column` specs (extra key columns such as ``skill`` are just more columns).
* :func:`plot_comparison` draws the figure: BC training loss (if given) and per-source steps to success and
  path length (bars = means from the rows, dots = single episodes where they are known).
* :func:`write_report` puts them on one page, ``report.md``, next to the PNG.

Rows are the dicts :func:`surrol_data.datasets.metrics.summarize` returns, plus a ``source`` key; demo
trajectories are summarised with the same metric code as policy rollouts (one ruler for both).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from surrol_data.datasets.trajectory import Trajectory
from surrol_data.datasets.metrics import Proficiency, summarize, trajectory_proficiency

REPORT_FILE = "report.md"
FIGURE_FILE = "comparison.png"


def _number(digits: int) -> Callable[[object], str]:
    return lambda v: f"{v:.{digits}f}"


def _percent(v) -> str:
    return f"{100.0 * v:.0f} %"


@dataclass(frozen=True)
class Column:
    key: str                                 # key in the row dict
    header: str                              # table header
    fmt: Callable[[object], str] = str       # applied to present, finite values; missing / nan → "—"


# The columns of a summarize() row, in the order the paper's tables use.
SUMMARY_COLUMNS: tuple[Column, ...] = (
    Column("source", "Source"),
    Column("episodes", "Episodes"),
    Column("success_rate", "Success rate", _percent),
    Column("final_success_rate", "Final success rate", _percent),
    Column("mean_steps_to_success", "Mean steps to complete", _number(1)),
    Column("mean_path_length_cm", "Mean path length (cm)", _number(2)),
    Column("mean_log_dimensionless_jerk", "Smoothness (LDLJ)", _number(2)),
    Column("mean_jaw_closures", "Jaw closures", _number(1)),
)


def _cell(value, fmt: Callable[[object], str]) -> str:
    if value is None or (isinstance(value, (float, np.floating)) and not math.isfinite(value)):
        return "—"
    # A pipe inside a cell would split the markdown table.
    return fmt(value).replace("|", "\\|")


def metrics_table_markdown(rows: Sequence[Mapping], columns: Sequence[Column] = SUMMARY_COLUMNS) -> str:
    """Markdown table, one line per row dict; a key missing from a row shows as "—"."""
    if not columns:
        raise ValueError("metrics_table_markdown: no columns given")
    head = "| " + " | ".join(c.header for c in columns) + " |"
    # Numbers right-aligned, the first (name) column left-aligned.
    rule = "|" + "|".join(":---" if i == 0 else "---:" for i in range(len(columns))) + "|"
    body = ["| " + " | ".join(_cell(row.get(c.key), c.fmt) for c in columns) + " |" for row in rows]
    return "\n".join([head, rule, *body]) + "\n"


def summary_rows(demos: Mapping[str, Sequence[Trajectory]] | None = None,
                 evaluations: Mapping[str, Mapping] | None = None) -> list[dict]:
    """Rows for the table: demo sources first (summarised here), then evaluation results as given."""
    clash = sorted(set(demos or {}) & set(evaluations or {}))
    if clash:
        # Same name twice would make two indistinguishable table rows and mix their dots in the figure.
        raise ValueError(f"summary_rows: {clash} named both a demo source and an evaluation; rename one "
                         "(e.g. 'oracle demos' / 'oracle rollouts')")
    rows = []
    for source, trajectories in (demos or {}).items():
        rows.append({"source": source, **summarize([trajectory_proficiency(t) for t in trajectories])})
    for name, summary in (evaluations or {}).items():
        rows.append({"source": name, **summary})
    return rows


def _loss_dict(training_loss) -> dict[str, list[float]]:
    if training_loss is None:
        return {}
    if isinstance(training_loss, Mapping):
        return {k: [float(v) for v in vals] for k, vals in training_loss.items() if len(vals)}
    return {"train": [float(v) for v in training_loss]} if len(training_loss) else {}


def plot_comparison(path: str | Path, rows: Sequence[Mapping], *,
                    episodes: Mapping[str, Sequence[Proficiency]] | None = None,
                    training_loss: Sequence[float] | Mapping[str, Sequence[float]] | None = None,
                    title: str | None = None) -> Path:
    """PNG with (a) the training loss per epoch (when given), (b) steps to success and (c) path length per source.

    ``rows``: one dict per source with ``source``, ``mean_steps_to_success`` and ``mean_path_length_cm``
    (bar heights). ``episodes``: per-source single-episode metrics, drawn as dots over the bars (successful
    episodes only, as the means are). ``training_loss``: a list (train) or a dict name → list, e.g.
    ``{"train": [...], "validation": [...]}``; drawn on a log scale when it spans more than a decade.
    """
    import matplotlib

    matplotlib.use("Agg")   # headless: reports are written on machines without a display
    import matplotlib.pyplot as plt

    if not rows:
        raise ValueError("plot_comparison: no rows to plot")
    losses = _loss_dict(training_loss)
    episodes = episodes or {}
    n_panels = 3 if losses else 2
    fig, axes = plt.subplots(1, n_panels, figsize=(4.6 * n_panels, 4.0), constrained_layout=True)
    axes = list(np.atleast_1d(axes))
    letters = iter("abc")

    if losses:
        ax = axes.pop(0)
        for name, values in losses.items():
            ax.plot(np.arange(1, len(values) + 1), values, marker="o" if len(values) <= 30 else None,
                    markersize=3, label=name)
        all_values = np.concatenate([np.asarray(v) for v in losses.values()])
        positive = all_values[all_values > 0]
        if len(positive) and positive.max() / positive.min() > 10:
            ax.set_yscale("log")
        ax.set_xlabel("epoch")
        ax.set_ylabel("loss")
        ax.set_title(f"({next(letters)}) BC training loss")
        ax.legend()
        ax.grid(alpha=0.3)

    sources = [str(r["source"]) for r in rows]
    # Each source's success rate under its name: steps and path are over successful episodes only, so a bar
    # means little without it.
    labels = [f"{s}\n{_cell(r.get('success_rate'), _percent)} success" for s, r in zip(sources, rows)]
    x = np.arange(len(sources))
    colors = [plt.get_cmap("tab10")(i % 10) for i in range(len(sources))]
    panels = [("mean_steps_to_success", "steps_to_success", "steps to success (steps)", "steps to success"),
              ("mean_path_length_cm", "path_length_cm", "path length to success (cm)", "path length")]
    for ax, (row_key, episode_key, ylabel, name) in zip(axes, panels):
        means = np.array([float(r.get(row_key, np.nan)) for r in rows])
        ax.bar(x, np.nan_to_num(means), color=colors, alpha=0.6, label="mean (successful episodes)")
        dotted = False
        rng = np.random.default_rng(0)   # fixed jitter: the same data gives the same picture
        for i, source in enumerate(sources):
            values = [getattr(p, episode_key) for p in episodes.get(source, []) if p.success]
            if values:
                ax.scatter(i + rng.uniform(-0.15, 0.15, len(values)), values, s=14, color="black", zorder=3,
                           label=None if dotted else "single episode")
                dotted = True
        for i, m in enumerate(means):
            if not np.isfinite(m):   # no successful episode: say so instead of drawing a zero bar
                ax.annotate("no success", (i, 0), ha="center", va="bottom", fontsize=8, rotation=90)
        ax.set_xticks(x, labels, rotation=20 if len(sources) > 3 else 0, ha="right" if len(sources) > 3 else "center")
        ax.set_xlabel("policy / demo source")
        ax.set_ylabel(ylabel)
        ax.set_title(f"({next(letters)}) {name} per source")
        ax.legend(fontsize=8)
        ax.grid(axis="y", alpha=0.3)

    if title:
        fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_report(out_dir: str | Path, title: str, *,
                 demos: Mapping[str, Sequence[Trajectory]] | None = None,
                 evaluations: Mapping[str, Mapping] | None = None,
                 training_loss: Sequence[float] | Mapping[str, Sequence[float]] | None = None,
                 rrd_path: str | Path | None = None,
                 columns: Sequence[Column] = SUMMARY_COLUMNS,
                 rows: Sequence[Mapping] | None = None,
                 intro: str = "",
                 sections: Sequence[tuple[str, str]] = ()) -> Path:
    """Write ``out_dir/report.md`` and ``out_dir/comparison.png``; return the report path.

    ``demos``: demo source label → its trajectories (summarised with the project's metrics).
    ``evaluations``: policy name → :func:`summarize` output, e.g. ``{"oracle": ..., "BC policy": ...}``.
    ``training_loss``: per-epoch BC loss, a list or a dict name → list (train / validation).
    ``rrd_path``: a Rerun recording to link (relative to the report when possible).
    ``rows``: ready-made table rows instead of ``demos``/``evaluations`` (e.g. one row per source × skill,
    with matching ``columns``). ``intro`` and ``sections`` ((heading, markdown) pairs) add free text.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if rows is None:
        rows = summary_rows(demos, evaluations)
    if not rows:
        raise ValueError("write_report: nothing to report; give demos, evaluations or rows")
    episodes = {source: [trajectory_proficiency(t) for t in trajs] for source, trajs in (demos or {}).items()}
    figure = plot_comparison(out_dir / FIGURE_FILE, rows, episodes=episodes, training_loss=training_loss)

    lines = [f"# {title}", ""]
    if intro:
        lines += [intro.strip(), ""]
    lines += ["## Results", "", metrics_table_markdown(rows, columns),
              "Success rate: success at any step; final success rate: success at the last step. Steps, path "
              "length and smoothness are means over successful episodes (path up to the first success, all "
              "arms summed); LDLJ is the log dimensionless jerk (higher = smoother); jaw closures are "
              "open→close transitions of the jaw command, mean over all episodes.", ""]
    lines += ["## Figure", "", f"![comparison of sources]({figure.name})", ""]
    losses = _loss_dict(training_loss)
    if losses:
        summary = ", ".join(f"{name}: {vals[0]:.4g} → {vals[-1]:.4g} (min {min(vals):.4g})"
                            for name, vals in losses.items())
        lines += ["## Training", "", f"BC loss over {max(len(v) for v in losses.values())} epochs — {summary}.", ""]
    if rrd_path is not None:
        rrd = Path(rrd_path)
        link = _relative_link(rrd, out_dir)
        from surrol_data.viz.open_command import rerun_open_command, web_view_command

        # from the report's folder: the native viewer needs a display; the web viewer serves it to a browser
        lines += ["## Recording", "",
                  f"Episodes in Rerun: [{rrd.name}]({link}) — open it from this folder with "
                  f"`{rerun_open_command(link)}` on a desktop, or serve it to a browser with "
                  f"`{web_view_command(link)}` (an SSH session, a container).", ""]
    for heading, text in sections:
        lines += [f"## {heading}", "", text.strip(), ""]

    report = out_dir / REPORT_FILE
    report.write_text("\n".join(lines))
    return report


def _relative_link(target: Path, base: Path) -> str:
    try:
        return Path(os.path.relpath(target.resolve(), base.resolve())).as_posix()
    except ValueError:   # different drives (Windows): fall back to the absolute path
        return target.resolve().as_posix()

"""Learning curves of two (or more) algos side by side, from finished run folders: the README's figure.

    python benchmarks/plot_curves.py ddpgbc=runs/NeedlePick/ddpgbc/script ddpgbc_warm=runs/NeedlePick/ddpgbc_warm/script \
        --out docs/learning_curves.png

Each ``name=folder`` is an algo; its runs are the ``seed*`` folders below ``folder`` (each with a
``metrics.jsonl``). Plotted: one panel per algo (evaluation success against env steps, every seed thin, the
median bold; epoch 0, after BC pre-training and before any env step, is the first point) and a last panel
with every algo's median on one axis. Runs logged with ``algo.params.probe=true`` add a second row: the
actor's RMS action distance from the BC actor it started as, on demo states (see ``algos/warm_probe.py``).
Printed: per algo the table the issue's criteria read — post-BC success, the lowest success over the first
10 online epochs and its ratio to the post-BC success, env steps to the first evaluation >= 90 % (per seed and
median), final success.

``--check`` tests the offline→online criteria, the first algo being the baseline and the others candidates,
and exits 1 when one fails: the baseline reaches 90 % within 100k env steps on every seed; every candidate
seed keeps its first 10 online epochs >= 0.5 × its post-BC success, and the candidate's median steps to
90 % is no more than the baseline's (a seed that never got there counts as infinitely slow).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

from surrol_data.algos.train import read_metrics

TARGET = 0.9
KEEP = 0.5             # the lowest online success over the first 10 epochs, as a share of the post-BC success
BASELINE_BUDGET = 100_000   # env steps within which the baseline must reach TARGET


def criteria(rows: list[dict]) -> dict:
    post_bc = rows[0]["success_rate"]
    first10 = [r["success_rate"] for r in rows if 1 <= r["epoch"] <= 10]
    hit = next((r["env_steps"] for r in rows if r["epoch"] > 0 and r["success_rate"] >= TARGET), None)
    return {"post_bc": post_bc, "min_first10": min(first10) if first10 else float("nan"),
            "epochs_seen": rows[-1]["epoch"], "steps_to_90": hit, "final": rows[-1]["success_rate"],
            "max_steps": rows[-1]["env_steps"]}


def check(results: dict[str, list[dict]]) -> list[str]:
    """The criteria that fail (empty: all met); ``results`` maps algo name to its seeds' :func:`criteria`,
    the first algo being the baseline."""
    names = list(results)
    base = results[names[0]]
    failures = [f"{names[0]} seed {i}: no evaluation >= {TARGET:.0%} within "
                f"{min(BASELINE_BUDGET, c['max_steps'])} env steps"
                + (f" (only {c['max_steps']} logged)" if c["max_steps"] < BASELINE_BUDGET else "")
                for i, c in enumerate(base) if c["steps_to_90"] is None or c["steps_to_90"] > BASELINE_BUDGET]
    base_median = median_steps_to_target(base)
    for name in names[1:]:
        for i, c in enumerate(results[name]):
            if c["epochs_seen"] < 10:
                failures.append(f"{name} seed {i}: only {c['epochs_seen']} online epochs logged, 10 needed")
            elif not c["min_first10"] >= KEEP * c["post_bc"]:
                failures.append(f"{name} seed {i}: success fell to {c['min_first10']:.2f} in the first 10 online "
                                f"epochs, below {KEEP} x post-BC {c['post_bc']:.2f}")
        median = median_steps_to_target(results[name])
        if median > base_median:
            failures.append(f"{name}: median steps to {TARGET:.0%} {median:.0f} > {names[0]}'s {base_median:.0f}")
    return failures


def median_steps_to_target(found: list[dict]) -> float:
    """Median env steps to the first evaluation >= TARGET; a seed that never got there (within what was
    logged) counts as infinitely slow, so the median is defined whenever most seeds got there."""
    return statistics.median(math.inf if c["steps_to_90"] is None else c["steps_to_90"] for c in found)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("algos", nargs="+", help="name=folder holding seed*/metrics.jsonl")
    parser.add_argument("--out", type=Path, default=Path("docs/learning_curves.png"))
    parser.add_argument("--title", default="NeedlePick, 100 script demos, reference protocol")
    parser.add_argument("--check", action="store_true", help="exit 1 unless the offline→online criteria hold")
    args = parser.parse_args()
    runs = {}
    for spec in args.algos:
        if "=" not in spec:
            raise SystemExit(f"error: {spec!r} is not name=folder")
        name, folder = spec.split("=", 1)
        seeds = sorted(p for p in Path(folder).glob("seed*") if (p / "metrics.jsonl").is_file())
        if not seeds:
            raise SystemExit(f"error: no seed*/metrics.jsonl under {folder}")
        runs[name] = {p.name: read_metrics(p) for p in seeds}
    probed = any("probe_pi_to_bc" in r for seeds in runs.values() for rows in seeds.values() for r in rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    console = Console(width=140)
    n_rows, n_cols = 1 + probed, len(runs) + 1
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(5 * n_cols, 3.8 * n_rows), sharex=True, squeeze=False)
    overlay = axes[0][-1]
    table = Table(title=f"offline→online criteria ({TARGET:.0%} target)")
    for col in ("algo", "seed", "post-BC", "min epochs 1-10", "ratio", "steps to 90%", "final", "epochs"):
        table.add_column(col, justify="right")
    results = {}
    for col, (name, seed_runs) in enumerate(runs.items()):
        ax = axes[0][col]
        curves, found = [], []
        for seed_name, rows in seed_runs.items():
            steps = [r["env_steps"] / 1000 for r in rows]
            success = [r["success_rate"] for r in rows]
            ax.plot(steps, success, lw=0.8, alpha=0.5, label=seed_name)
            if probed and "probe_pi_to_bc" in rows[-1]:
                axes[1][col].plot(steps, [r.get("probe_pi_to_bc", float("nan")) for r in rows], lw=0.8,
                                  label=seed_name)
            curves.append(success)
            c = criteria(rows)
            found.append(c)
            table.add_row(name, seed_name, f"{c['post_bc']:.2f}", f"{c['min_first10']:.2f}",
                          f"{c['min_first10'] / c['post_bc']:.2f}" if c["post_bc"] else "-",
                          "-" if c["steps_to_90"] is None else str(c["steps_to_90"]), f"{c['final']:.2f}",
                          str(c["epochs_seen"]))
        results[name] = found
        n = min(len(c) for c in curves)
        median = [statistics.median(c[e] for c in curves) for e in range(n)]
        median_steps = [r["env_steps"] / 1000 for r in next(iter(seed_runs.values()))][:n]
        ax.plot(median_steps, median, lw=2.2, color="black", label="median")
        overlay.plot(median_steps, median, lw=2.0, label=f"{name} (median of {len(curves)})")
        med_hit = median_steps_to_target(found)
        table.add_row(name, "median", f"{statistics.median(c['post_bc'] for c in found):.2f}",
                      f"{statistics.median(c['min_first10'] for c in found):.2f}", "",
                      "-" if math.isinf(med_hit) else f"{med_hit:.0f}", f"{statistics.median(c['final'] for c in found):.2f}", "")
        ax.set_title(name)
    for col, ax in enumerate(axes[0]):
        ax.axhline(TARGET, ls=":", color="grey")
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    overlay.set_title("medians")
    axes[0][0].set_ylabel("evaluation success (last step)")
    if probed:
        axes[1][0].set_ylabel("RMS action distance\nfrom the BC actor (demo states)")
        axes[1][-1].axis("off")
        top = max(ax.get_ylim()[1] for ax in axes[1][:-1] if ax.lines)
        for ax in axes[1][:-1]:
            ax.grid(alpha=0.3)
            ax.set_ylim(0, top)
            if not ax.lines:
                ax.text(0.5, 0.5, "not logged (algo.params.probe=false)", ha="center", transform=ax.transAxes)
    for ax in axes[-1]:
        ax.set_xlabel("env steps (thousands)")
    fig.suptitle(args.title)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    console.print(table)
    console.print(f"wrote {args.out}")
    if args.check:
        failures = check(results)
        for line in failures:
            console.print(f"[red]FAIL[/red] {line}")
        if failures:
            return 1
        console.print("[green]PASS[/green] offline→online criteria met")
    return 0


if __name__ == "__main__":
    sys.exit(main())

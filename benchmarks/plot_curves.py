"""Learning curves of two (or more) algos side by side, from finished run folders: the README's figure.

    python benchmarks/plot_curves.py ddpgbc=runs/NeedlePick/ddpgbc/script ddpgbc_warm=runs/NeedlePick/ddpgbc_warm/script \
        --out docs/learning_curves.png

Each ``name=folder`` is an algo; its runs are the ``seed*`` folders below ``folder`` (each with a
``metrics.jsonl``). Plotted: evaluation success against env steps, every seed thin, the median bold; epoch 0
(after BC pre-training, no env steps yet) is the first point. Printed: per algo the table the issue's
criteria read — post-BC success, the lowest success over the first 10 online epochs and its ratio to the
post-BC success, and env steps to the first evaluation >= 90 % (per seed and median).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

from surrol_data.algos.train import read_metrics

TARGET = 0.9


def criteria(rows: list[dict]) -> dict:
    post_bc = rows[0]["success_rate"]
    first10 = [r["success_rate"] for r in rows if 1 <= r["epoch"] <= 10]
    hit = next((r["env_steps"] for r in rows if r["epoch"] > 0 and r["success_rate"] >= TARGET), None)
    return {"post_bc": post_bc, "min_first10": min(first10) if first10 else float("nan"),
            "epochs_seen": rows[-1]["epoch"], "steps_to_90": hit, "final": rows[-1]["success_rate"],
            "max_steps": rows[-1]["env_steps"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("algos", nargs="+", help="name=folder holding seed*/metrics.jsonl")
    parser.add_argument("--out", type=Path, default=Path("docs/learning_curves.png"))
    parser.add_argument("--title", default="NeedlePick, 100 script demos, reference protocol")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    console = Console(width=140)
    fig, axes = plt.subplots(1, len(args.algos), figsize=(5.5 * len(args.algos), 4), sharey=True, squeeze=False)
    table = Table(title=f"offline→online criteria ({TARGET:.0%} target)")
    for col in ("algo", "seed", "post-BC", "min epochs 1-10", "ratio", "steps to 90%", "final", "epochs"):
        table.add_column(col, justify="right")
    for ax, spec in zip(axes[0], args.algos):
        if "=" not in spec:
            raise SystemExit(f"error: {spec!r} is not name=folder")
        name, folder = spec.split("=", 1)
        seeds = sorted(p for p in Path(folder).glob("seed*") if (p / "metrics.jsonl").is_file())
        if not seeds:
            raise SystemExit(f"error: no seed*/metrics.jsonl under {folder}")
        curves, found = [], []
        for seed_dir in seeds:
            rows = read_metrics(seed_dir)
            steps = [r["env_steps"] / 1000 for r in rows]
            success = [r["success_rate"] for r in rows]
            ax.plot(steps, success, lw=0.8, alpha=0.5, label=seed_dir.name)
            curves.append(success)
            c = criteria(rows)
            found.append(c)
            table.add_row(name, seed_dir.name, f"{c['post_bc']:.2f}", f"{c['min_first10']:.2f}",
                          f"{c['min_first10'] / c['post_bc']:.2f}" if c["post_bc"] else "-",
                          "-" if c["steps_to_90"] is None else str(c["steps_to_90"]), f"{c['final']:.2f}",
                          str(c["epochs_seen"]))
        n = min(len(c) for c in curves)
        median = [statistics.median(c[e] for c in curves) for e in range(n)]
        ax.plot([r["env_steps"] / 1000 for r in read_metrics(seeds[0])][:n], median, lw=2.2, color="black",
                label="median")
        hits = [c["steps_to_90"] for c in found]
        med_hit = statistics.median(hits) if all(h is not None for h in hits) else None
        table.add_row(name, "median", f"{statistics.median(c['post_bc'] for c in found):.2f}",
                      f"{statistics.median(c['min_first10'] for c in found):.2f}", "",
                      "-" if med_hit is None else f"{med_hit:.0f}", f"{statistics.median(c['final'] for c in found):.2f}", "")
        ax.axhline(TARGET, ls=":", color="grey")
        ax.set_title(name)
        ax.set_xlabel("env steps (thousands)")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    axes[0][0].set_ylabel("evaluation success (last step)")
    fig.suptitle(args.title)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    console.print(table)
    console.print(f"wrote {args.out}")


if __name__ == "__main__":
    sys.exit(main())

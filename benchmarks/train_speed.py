"""Training speed and sample efficiency of DDPG+BC+HER on NeedlePick: the issue-6 targets.

    python benchmarks/train_speed.py --seeds 0 1 2                 # train 3 seeds (sequentially), then the table
    python benchmarks/train_speed.py --runs runs/NeedlePick/ddpgbc/script/seed*   # only summarise finished runs

Each run is composed from configs/ exactly as `surrol-data train` would (default: algo=ddpgbc task=NeedlePick
demos=script experiment=reference) with extra Hydra overrides after ``--``. Missing script demos are recorded first
(100 oracle episodes). The table: per seed, env steps, wall time, env steps/s (whole run and collection
only), update iterations/s, the first evaluation with success >= 90 % (env steps and wall seconds), the best
and final success; then the median over seeds. Targets: >= 90 % within 100k env steps, 100k steps <= 15 min.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

REPO = Path(__file__).resolve().parents[1]
TARGET = 0.9


def summarise(rows: list[dict]) -> dict:
    online = [r for r in rows if r["epoch"] > 0]
    last = rows[-1]
    collect_s = sum(r.get("time_collect_s", 0.0) for r in online)
    update_s = sum(r.get("time_update_s", 0.0) for r in online)
    hit = next((r for r in rows if r["success_rate"] >= TARGET), None)
    return {
        "env_steps": last["env_steps"], "wall_s": last["wall_s"],
        "steps_per_s": last["env_steps"] / last["wall_s"] if last["wall_s"] else float("nan"),
        "collect_steps_per_s": last["env_steps"] / collect_s if collect_s else float("nan"),
        "updates_per_s": last["updates"] / update_s if update_s else float("nan"),
        "steps_to_90": hit["env_steps"] if hit else None, "wall_to_90_s": hit["wall_s"] if hit else None,
        "best_success": max(r["success_rate"] for r in rows), "final_success": last["success_rate"],
        "curve": [round(r["success_rate"], 2) for r in rows],
    }


def print_table(console: Console, results: dict[str, dict]) -> None:
    table = Table(title=f"training speed and time to {TARGET:.0%} eval success")
    cols = ("run", "env steps", "wall min", "env steps/s", "collect steps/s", "updates/s", "steps to 90%",
            "min to 90%", "best", "final")
    for c in cols:
        table.add_column(c, justify="right")

    def fmt(v, spec):
        return "-" if v is None else format(v, spec)

    for name, s in results.items():
        table.add_row(name, str(s["env_steps"]), f"{s['wall_s'] / 60:.1f}", f"{s['steps_per_s']:.0f}",
                      f"{s['collect_steps_per_s']:.0f}", f"{s['updates_per_s']:.0f}", fmt(s["steps_to_90"], "d"),
                      fmt(None if s["wall_to_90_s"] is None else s["wall_to_90_s"] / 60, ".1f"),
                      f"{s['best_success']:.2f}", f"{s['final_success']:.2f}")
    if len(results) > 1:
        def med(key):
            values = [s[key] for s in results.values() if s[key] is not None]
            return statistics.median(values) if len(values) == len(results) else None
        table.add_row("median", f"{med('env_steps'):.0f}", f"{med('wall_s') / 60:.1f}", f"{med('steps_per_s'):.0f}",
                      f"{med('collect_steps_per_s'):.0f}", f"{med('updates_per_s'):.0f}",
                      fmt(med("steps_to_90"), ".0f"),
                      fmt(None if med("wall_to_90_s") is None else med("wall_to_90_s") / 60, ".1f"),
                      f"{med('best_success'):.2f}", f"{med('final_success'):.2f}")
    console.print(table)
    for name, s in results.items():
        console.print(f"{name} success per epoch: {s['curve']}")


def train_seed(seed: int, out: Path, demos: Path, overrides: list[str]) -> Path:
    from hydra import compose, initialize_config_dir

    from surrol_data.algos.train import train
    from surrol_data.train_app import config_dir, to_train_config

    run_dir = out / f"seed{seed}"
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("config", overrides=["algo=ddpgbc", "task=NeedlePick", "demos=script", "experiment=reference",
                                           f"demos.path={demos}", f"run_dir={run_dir}", f"seed={seed}",
                                           "resume=true", *overrides])
        train(to_train_config(cfg))  # without a Hydra runtime, relative paths resolve against the cwd
    return run_dir


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "train_speed")
    parser.add_argument("--demos", type=Path, default=REPO / "datasets" / "NeedlePick_script")
    parser.add_argument("--runs", type=Path, nargs="*", help="summarise these finished run folders instead of training")
    args, overrides = parser.parse_known_args()
    overrides = [o for o in overrides if o != "--"]
    console = Console(width=160)
    from surrol_data.algos.train import read_metrics

    if args.runs:
        results = {str(p): summarise(read_metrics(p)) for p in args.runs}
    else:
        if not args.demos.exists():
            from surrol_data.collect.script_source import collect_script

            console.print(f"recording 100 script demos into {args.demos}")
            collect_script("NeedlePick", 100, args.demos)
        results = {}
        for seed in args.seeds:
            run_dir = train_seed(seed, args.out, args.demos.resolve(), overrides)
            results[f"seed {seed}"] = summarise(read_metrics(run_dir))
    print_table(console, results)


if __name__ == "__main__":
    sys.exit(main())

"""Training speed and sample efficiency of DDPG+BC+HER on NeedlePick: the issue-6 targets.

    python benchmarks/train_speed.py --seeds 0 1 2                 # train 3 seeds (sequentially), then the table
    python benchmarks/train_speed.py --runs runs/NeedlePick/ddpgbc/script/seed*   # only summarise finished runs
    python benchmarks/train_speed.py --protocol paper --epochs 3  # the batched path on the paper's 12-run study

``--protocol paper`` trains the Table I study (3 demo sources × 4 seeds, epochs of 40 × 150-step episodes) as one
batched ensemble for ``--epochs`` epochs and prints, per epoch: collect / update / eval seconds, env steps/s,
member updates/s, and the achieved GFLOP/s of the updates against a matmul peak measured in the same run; then
the baseline (the single-run path, ``--baseline-epochs`` epochs of one run, same run) and the extrapolation of
both to the full 100-epoch study. Demo sources missing on disk (``<demos-root>/NeedlePick_human`` for
expert/novice) are replaced by the script demos and the table says so: the cost does not depend on the source.

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


# ---------------------------------------------------------------------------------------------- paper protocol
def update_flops(obs_dim: int, goal_dim: int, act_dim: int, hidden: list[int], batch: int, demo_batch: int,
                 q_filter: bool) -> float:
    """Matmul FLOPs of one DDPG+BC update iteration of one run (2 FLOPs per multiply-add).

    Per batch: critic step = target actor + target critic forward, critic forward and backward (2×) →
    A + 4C; actor step = actor forward, critic forward, critic backward for the action only (1×), actor
    backward (2×) → 3A + 2C; the Q-filter adds two target-critic forwards on the demo batch.
    """
    def macs(dims):
        return sum(a * b for a, b in zip(dims[:-1], dims[1:]))
    a = macs([obs_dim + goal_dim, *hidden, act_dim])
    c = macs([obs_dim + goal_dim + act_dim, *hidden, 1])
    per_sample = 4 * a + 6 * c
    return 2.0 * (batch * per_sample + demo_batch * (per_sample + (2 * c if q_filter else 0)))


def matmul_peak_gflops(members: int, batch: int, width: int, repeats: int = 200) -> float:
    """Median GFLOP/s of the batched 256-wide matmul the ensemble's hidden layers run, on this process's threads."""
    import time

    import torch

    x, w = torch.randn(members, batch, width), torch.randn(members, width, width)
    for _ in range(10):
        torch.bmm(x, w)
    times = []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(repeats):
            torch.bmm(x, w)
        times.append((time.perf_counter() - t) / repeats)
    return 2.0 * members * batch * width * width / statistics.median(times) / 1e9


def paper_protocol(args, console: Console) -> None:
    import time

    import torch
    from hydra import compose, initialize_config_dir

    from surrol_data.algos.train import train
    from surrol_data.algos.train_batched import train_batched
    from surrol_data.train_app import config_dir, to_train_config

    torch.set_num_threads(1)
    script = args.demos.resolve()
    human = args.demos.parent.resolve() / "NeedlePick_human"
    sources = {"script": script, "expert": human if human.exists() else script,
               "novice": human if human.exists() else script}
    substituted = [k for k, v in sources.items() if k != "script" and v == script]
    out = args.out / "paper"
    jobs = []
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        for source, path in sources.items():
            for seed in args.paper_seeds:
                demos = source if path != script else "script"
                overrides = ["algo=ddpgbc", "task=NeedlePick", f"demos={demos}", "experiment=paper",
                             f"demos.path={path}", f"experiment.epochs={args.epochs}", f"seed={seed}",
                             f"run_dir={out / source / f'seed{seed}'}", "tensorboard=false", "progress=false",
                             *args.overrides]
                jobs.append(to_train_config(compose("config", overrides=overrides)))
        baseline = to_train_config(compose("config", overrides=[
            "algo=ddpgbc", "task=NeedlePick", "demos=script", "experiment=paper", f"demos.path={script}",
            f"experiment.epochs={args.baseline_epochs}", "seed=0", f"run_dir={out / 'single'}",
            "tensorboard=false", "progress=false", *args.overrides]))
    cfg0 = jobs[0]
    hidden = list(cfg0.learner_params.get("hidden_sizes", [256, 256, 256]))
    flops = update_flops(19, 3, 5, hidden, int(cfg0.learner_params["batch_size"]),
                         int(cfg0.learner_params["demo_batch_size"]), bool(cfg0.learner_params["q_filter"]))
    peak = matmul_peak_gflops(len(jobs), int(cfg0.learner_params["batch_size"]), hidden[0])
    console.print(f"{len(jobs)} runs, {flops / 1e9:.2f} GFLOP per run-update, matmul peak {peak:.0f} GFLOP/s "
                  f"(1 thread, ({len(jobs)}, 128, {hidden[0]}) x ({hidden[0]}, {hidden[0]}) bmm)"
                  + (f"; {', '.join(substituted)} demos replaced by script demos (no NeedlePick_human)" if substituted else ""))
    peak_before = peak
    t0 = time.perf_counter()
    runs = train_batched(jobs, overlap=not args.no_overlap, n_workers=cfg0.schedule.n_envs, progress=True)
    batched_wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    single_rows = train(baseline) if args.baseline_epochs > 0 else []
    single_wall = time.perf_counter() - t0

    # the machine is shared: take the better of two peak measurements, one before and one after the training
    peak = max(peak_before, matmul_peak_gflops(len(jobs), int(cfg0.learner_params["batch_size"]), hidden[0]))
    console.print(f"matmul peak: {peak_before:.0f} GFLOP/s before, {peak:.0f} GFLOP/s best (used below)")
    rows = runs[0]
    m = len(jobs)
    table = Table(title=f"paper protocol, {m} runs as one batched ensemble (overlap={not args.no_overlap})")
    for c in ("epoch", "collect s", "update s", "eval s", "epoch s", "env steps/s", "run-updates/s", "GFLOP/s",
              "of peak", "success (min/median/max)"):
        table.add_column(c, justify="right")
    prev_wall = 0.0
    epoch_walls = []
    for e, r in enumerate(rows):
        wall = r["wall_s"] - prev_wall
        prev_wall = r["wall_s"]
        succ = sorted(run[e]["success_rate"] for run in runs)
        if r["epoch"] == 0:
            table.add_row("0 (BC)", "-", "-", f"{r['time_eval_s']:.1f}", f"{wall:.1f}", "-", "-", "-", "-",
                          f"{succ[0]:.2f}/{statistics.median(succ):.2f}/{succ[-1]:.2f}")
            continue
        epoch_walls.append(wall)
        steps = m * (r["env_steps"] - rows[e - 1]["env_steps"]) + m * cfg0.schedule.eval_episodes * cfg0.schedule.max_episode_steps
        updates = m * (r["updates"] - rows[e - 1]["updates"])
        gflops = updates * flops / r["time_update_s"] / 1e9 if r["time_update_s"] else float("nan")
        table.add_row(str(r["epoch"]), f"{r['time_collect_s']:.1f}", f"{r['time_update_s']:.1f}",
                      f"{r['time_eval_s']:.1f}", f"{wall:.1f}", f"{steps / wall:.0f}",
                      f"{updates / r['time_update_s']:.0f}", f"{gflops:.0f}", f"{gflops / peak:.0%}",
                      f"{succ[0]:.2f}/{statistics.median(succ):.2f}/{succ[-1]:.2f}")
    console.print(table)
    full_epochs = 100
    if epoch_walls:
        per_epoch = statistics.median(epoch_walls)
        batched_full = rows[0]["wall_s"] + full_epochs * per_epoch
        console.print(f"batched: {batched_wall:.0f} s for {args.epochs} epochs; median epoch {per_epoch:.1f} s -> "
                      f"EXTRAPOLATED full study ({m} runs x {full_epochs} epochs): {batched_full / 3600:.2f} h")
    if single_rows:
        online = [r for r in single_rows if r["epoch"] > 0]
        walls = [b["wall_s"] - a["wall_s"] for a, b in zip(single_rows, single_rows[1:])]
        per_epoch_single = statistics.median(walls)
        single_full = m * (single_rows[0]["wall_s"] + full_epochs * per_epoch_single)
        ups = statistics.median([r["updates"] - p["updates"] for p, r in zip(single_rows, single_rows[1:])]) / \
            statistics.median([r["time_update_s"] for r in online])
        console.print(f"baseline, single-run path (same run, {args.baseline_epochs} epoch(s) of 1 run): median epoch "
                      f"{per_epoch_single:.1f} s, {ups:.0f} updates/s ({ups * flops / 1e9:.0f} GFLOP/s); "
                      f"EXTRAPOLATED {m} runs x {full_epochs} epochs one after another: {single_full / 3600:.2f} h")
        if epoch_walls:
            console.print(f"batched / serial single runs, per epoch of all {m} runs: "
                          f"{per_epoch / (m * per_epoch_single):.2f}x the time ({m * per_epoch_single / per_epoch:.1f}x faster)")
    console.print(f"(the single-run baseline took {single_wall:.0f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--protocol", choices=("reference", "paper"), default="reference",
                        help="paper: time the 12-run paper study on the batched path (see above)")
    parser.add_argument("--epochs", type=int, default=3, help="--protocol paper: epochs to time")
    parser.add_argument("--paper-seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    parser.add_argument("--baseline-epochs", type=int, default=1, help="--protocol paper: single-run epochs to time")
    parser.add_argument("--no-overlap", action="store_true", help="--protocol paper: serial collect-then-update")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "train_speed")
    parser.add_argument("--demos", type=Path, default=REPO / "datasets" / "NeedlePick_script")
    parser.add_argument("--runs", type=Path, nargs="*", help="summarise these finished run folders instead of training")
    args, overrides = parser.parse_known_args()
    overrides = [o for o in overrides if o != "--"]
    args.overrides = overrides
    console = Console(width=160)
    if args.protocol == "paper":
        if not args.demos.exists():
            from surrol_data.collect.script_source import collect_script

            console.print(f"recording 100 script demos into {args.demos}")
            collect_script("NeedlePick", 100, args.demos)
        paper_protocol(args, console)
        return
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

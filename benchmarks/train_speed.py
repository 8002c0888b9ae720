"""Training speed and sample efficiency of DDPG+BC+HER on NeedlePick: the issue-6 targets.

    python benchmarks/train_speed.py --seeds 0 1 2                 # train 3 seeds (sequentially), then the table
    python benchmarks/train_speed.py --runs runs/NeedlePick/ddpgbc/script/seed*   # only summarise finished runs
    python benchmarks/train_speed.py --protocol paper --epochs 3  # the batched path on the paper's 12-run study
    python benchmarks/train_speed.py --protocol paper --study docs/results/table1   # cost of the study's finished runs
    python benchmarks/train_speed.py --protocol paper --actors-from docs/results/table1 --epochs 1 --cycles 2 \
        --offline-steps 0     # the CPU of an epoch per phase, on the step mix of the study's learned policies
    python benchmarks/train_speed.py --compare-learning docs/results/table1/runs/expert runs/after/expert
                              # success at epochs 50, 100 of two sets of seeds within each other's intervals
    python benchmarks/train_speed.py --protocol paper --threads-ab --no-floor --epochs 3 --cycles 5 \
        --offline-steps 50 -- experiment.eval_episodes=4      # learner at 1 thread vs widening to idle cores

``--protocol paper`` first measures this machine's compute floor for the Table I study in CPU time (one env step
on one core, one batched 12-run update, the matmul peak; valid on a shared machine), then trains the study
(3 demo sources × 4 seeds, epochs of 40 × 150-step episodes) as one batched ensemble for ``--epochs`` epochs
(``--cycles`` shortens them) and prints, per epoch: collect / update / eval seconds, the learner's and the env
workers' CPU seconds and how many cores they kept busy, env steps/s, member updates/s, and the achieved GFLOP/s
of the updates against the matmul peak; then the extrapolation to the full 100-epoch study from wall time and
from CPU time (what a quiet machine would take), and the baseline (the single-run path, ``--baseline-epochs``
epochs of one run, same run). Demo sources missing on disk (``<demos-root>/NeedlePick_human`` for
expert/novice) are replaced by the script demos and the table says so: the cost does not depend on the source.

Each run is composed from configs/ exactly as `surrol-data train` would (default: algo=ddpgbc task=NeedlePick
demos=script experiment=reference) with extra Hydra overrides after ``--``. Missing script demos are recorded first
(100 oracle episodes). The table: per seed, env steps, wall time, env steps/s (whole run and collection
only), update iterations/s, the first evaluation with success >= 90 % (env steps and wall seconds), the best
and final success; then the median over seeds. Targets: >= 90 % within 100k env steps, 100k steps <= 15 min.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
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
    """GFLOP/s of the batched 256-wide matmul the ensemble's hidden layers run, on one thread, in CPU time
    (``time.thread_time``): what the core delivers while it runs this thread, whatever else shares the machine."""
    import torch

    x, w = torch.randn(members, batch, width), torch.randn(members, width, width)
    for _ in range(10):
        torch.bmm(x, w)
    times = []
    for _ in range(5):
        t = time.thread_time()
        for _ in range(repeats):
            torch.bmm(x, w)
        times.append((time.thread_time() - t) / repeats)
    return 2.0 * members * batch * width * width / statistics.median(times) / 1e9


def env_step_cpu_s(env_id: str, steps: int, episodes: int = 3) -> float:
    """Median CPU seconds of one env step (random actions, resets excluded), one env on one core."""
    import numpy as np

    from surrol_data.algos.train import make_env

    env = make_env(env_id, steps)
    rng = np.random.default_rng(0)
    per_step = []
    for ep in range(episodes):
        env.reset(seed=ep)
        t = time.thread_time()
        for _ in range(steps):
            env.step(rng.uniform(-1.0, 1.0, env.action_space.shape).astype(np.float32))
        per_step.append((time.thread_time() - t) / steps)
    env.close()
    return statistics.median(per_step)


def ensemble_update_cpu_s(members: int, learner_params: dict, her_k: int, repeats: int = 10) -> float:
    """Median CPU seconds of one batched update of ``members`` NeedlePick-sized members (random buffers)."""
    import numpy as np

    from surrol_data.algos.ddpg import DDPGConfig
    from surrol_data.algos.ensemble import EnsembleDDPG
    from surrol_data.algos.replay import EpisodeReplay

    params = {k: (tuple(v) if k == "hidden_sizes" else v) for k, v in learner_params.items()}
    learner = EnsembleDDPG(19, 3, 5, DDPGConfig(**params), list(range(members)))
    reward = lambda ag, g: -(np.linalg.norm(ag - g, axis=-1) > 0.05).astype(np.float32)  # noqa: E731
    replays, demos = [], []
    for i in range(members):
        rng = np.random.default_rng(i)
        pair = [EpisodeReplay(200, 150, 19, 3, 5, reward, her_k, seed=i) for _ in range(2)]
        for buf in pair:
            for _ in range(50):
                buf.add_episode(rng.standard_normal((151, 19)), rng.standard_normal((151, 3)),
                                rng.standard_normal((150, 3)), rng.uniform(-1, 1, (150, 5)))
        learner.inputs[i].update(pair[0].obs[:50].reshape(-1, 19), pair[0].g[:50].reshape(-1, 3))
        replays.append(pair[0])
        demos.append(pair[1])
    for _ in range(3):
        learner.update(replays, demos)
    times = []
    for _ in range(5):
        t = time.thread_time()
        for _ in range(repeats):
            learner.update(replays, demos)
        times.append((time.thread_time() - t) / repeats)
    return statistics.median(times)


def compute_floor(console: Console, cfg0, m: int, flops: float, peak: float, full_epochs: int) -> None:
    """What this machine cannot go below, measured: env steps (training + evaluation) at one env per core, and
    the updates at the matmul peak; both over the machine's cores, with nothing wasted."""
    s = cfg0.schedule
    cores = os.cpu_count() or 1
    step_s = env_step_cpu_s(cfg0.env_id, s.max_episode_steps)
    upd_s = ensemble_update_cpu_s(m, cfg0.learner_params, s.her_k)
    per_epoch_steps = s.cycles * s.episodes_per_cycle * s.max_episode_steps
    eval_steps = s.eval_episodes * s.max_episode_steps
    steps = m * (full_epochs * (per_epoch_steps + eval_steps) + eval_steps)
    updates = full_epochs * s.cycles * s.updates_per_cycle          # ensemble updates (each: all m members)
    env_core_s = steps * step_s
    upd_core_s, upd_peak_core_s = updates * upd_s, updates * m * flops / (peak * 1e9)
    table = Table(title=f"compute floor of the full study on this machine ({m} runs x {full_epochs} epochs, {cores} cores)")
    for c in ("work", "amount", "CPU per unit", "core-hours", f"hours on {cores} cores"):
        table.add_column(c, justify="right")
    table.add_row("env steps (train + eval)", f"{steps / 1e6:.2f} M", f"{step_s * 1e3:.2f} ms/step "
                  f"({1 / step_s:.0f} steps/s/core)", f"{env_core_s / 3600:.2f}", f"{env_core_s / 3600 / cores:.2f}")
    table.add_row("updates at matmul peak", f"{updates * m / 1e3:.0f} k run-updates",
                  f"{flops / 1e9:.2f} GFLOP at {peak:.0f} GFLOP/s", f"{upd_peak_core_s / 3600:.2f}",
                  f"{upd_peak_core_s / 3600 / cores:.2f}")
    table.add_row("updates as implemented", f"{updates / 1e3:.0f} k {m}-run updates",
                  f"{upd_s * 1e3:.0f} ms = {m * flops / upd_s / 1e9:.0f} GFLOP/s ({m * flops / upd_s / 1e9 / peak:.0%})",
                  f"{upd_core_s / 3600:.2f}", f"{upd_core_s / 3600 / cores:.2f}")
    table.add_row("floor (env + updates at peak)", "", "", f"{(env_core_s + upd_peak_core_s) / 3600:.2f}",
                  f"{(env_core_s + upd_peak_core_s) / 3600 / cores:.2f}")
    table.add_row("floor as implemented (env + updates)", "", "", f"{(env_core_s + upd_core_s) / 3600:.2f}",
                  f"{(env_core_s + upd_core_s) / 3600 / cores:.2f}")
    console.print(table)


def threads_ab(console: Console, jobs: list, args) -> None:
    """The learner at its configured threads (A) against widening to the cores the workers leave idle (B): the
    same ensemble trained twice, A, B, A, B, … for ``--ab-rounds`` rounds, each from scratch; per-epoch medians."""
    from surrol_data.algos.train_batched import train_batched

    per = {False: [], True: []}
    for _ in range(args.ab_rounds):
        for widen in (False, True):
            rows = train_batched(jobs, overlap=not args.no_overlap, n_workers=jobs[0].schedule.n_envs,
                                 progress=True, widen_threads=widen)[0]
            for prev, r in zip(rows, rows[1:]):
                per[widen].append((r["wall_s"] - prev["wall_s"], r["time_update_s"], r["time_collect_s"],
                                   r["time_eval_s"]))
    table = Table(title=f"learner threads, {len(jobs)} runs, {jobs[0].schedule.cycles} cycles per epoch, "
                        f"{args.ab_rounds} rounds of A then B (medians over online epochs)")
    for c in ("learner", "epochs", "epoch s", "update s", "collect s", "eval s", "epoch time vs A"):
        table.add_column(c, justify="right")
    base = statistics.median(e[0] for e in per[False])
    for widen, label in ((False, f"A: fixed at torch_threads={jobs[0].schedule.torch_threads}"),
                         (True, "B: widens to idle cores when faster")):
        med = [statistics.median(e[k] for e in per[widen]) for k in range(4)]
        table.add_row(label, str(len(per[widen])), *(f"{x:.1f}" for x in med), f"{med[0] / base:.2f}x")
    console.print(table)


def study_cost(study: Path, console: Console, cores: int) -> None:
    """The measured cost of a study's finished runs (their run.json: CPU seconds of the batch's learner and env
    workers, shared equally by its members, and the batch's wall time), on the step mix of the policies they
    learned; and the whole study's projected CPU and wall time on ``cores`` cores."""
    import json

    records = sorted((json.loads(p.read_text()) for p in study.glob("runs/*/seed*/run.json")),
                     key=lambda r: (r["seed"], r["source"]))
    if not records:
        sys.exit(f"no finished runs (runs/*/seed*/run.json) under {study}")
    table = Table(title=f"Cost of one study run ({study})")
    for col in ("run", "epochs", "batched with", "CPU h per run", "wall h of its batch", "CPU s per epoch", "CPU"):
        table.add_column(col, justify="right" if col not in ("run", "CPU") else "left")
    per_run = []
    for r in records:
        t = r["time"]
        per_run.append(t["cpu_s"])
        table.add_row(f"{r['source']}/{r['seed']}", str(r["epochs"]), str(t["batched_members"] - 1),
                      f"{t['cpu_s'] / 3600:.2f}", f"{t['wall_s'] / 3600:.2f}", f"{t['cpu_s'] / r['epochs']:.1f}",
                      r["code"]["cpu"])
    console.print(table)
    median = statistics.median(per_run)
    total = 12 * median
    console.print(f"median CPU per run {median / 3600:.2f} h; 12 runs: {total / 3600:.1f} CPU h = "
                  f"{total / 3600 / cores:.1f} h on {cores} fully busy cores (the matched and the natural study "
                  f"each)")


def cpu_breakdown(console: Console, timed: list, m: int, s, s_full, full_epochs: int) -> dict:
    """Where one protocol epoch's CPU goes, per run (medians of the timed epochs, in CPU seconds: valid on a
    shared machine): the env workers' training episodes and evaluation episodes, the learner's updates and the rest
    of its work (episodes into the buffers, normalisers, policy snapshots, scoring, checkpoints); shortened epochs
    scaled to the protocol's cycles. And the CPU hours of one run of ``full_epochs`` epochs at that rate."""
    scale = s_full.cycles / s.cycles
    train_steps = s.cycles * s.episodes_per_cycle * s.max_episode_steps
    phases = {"env: training episodes": [], "env: evaluation episodes": [], "learner: updates": [],
              "learner: other": []}
    for r, _ in timed:
        collect = r["time_cpu_envs_s"] - r["time_cpu_envs_eval_s"]
        phases["env: training episodes"].append(collect * scale / m)
        phases["env: evaluation episodes"].append(r["time_cpu_envs_eval_s"] / m)
        phases["learner: updates"].append(r["time_cpu_learner_update_s"] * scale / m)
        phases["learner: other"].append((r["time_cpu_learner_s"] - r["time_cpu_learner_update_s"]) * scale / m)
    med = {k: statistics.median(v) for k, v in phases.items()}
    total = sum(med.values())
    table = Table(title=f"CPU of one protocol epoch per run ({m} runs batched; medians of {len(timed)} epochs, "
                        f"{s.cycles} of {s_full.cycles} cycles scaled)")
    for c in ("phase", "CPU s per run-epoch", "share", "per unit"):
        table.add_column(c, justify="right" if c != "phase" else "left")
    units = {"env: training episodes": (s_full.cycles * s_full.episodes_per_cycle * s_full.max_episode_steps, "step"),
             "env: evaluation episodes": (s_full.eval_episodes * s_full.max_episode_steps, "step"),
             "learner: updates": (s_full.cycles * s_full.updates_per_cycle, "update")}
    for k, v in med.items():
        n, unit = units.get(k, (None, ""))
        table.add_row(k, f"{v:.2f}", f"{v / total:.0%}", f"{v / n * 1e3:.2f} ms per {unit}" if n else "")
    table.add_row("total", f"{total:.2f}", "100%", f"-> {full_epochs * total / 3600:.2f} CPU h per run "
                                                   f"({full_epochs} epochs)")
    console.print(table)
    console.print(f"(env CPU per step here: {train_steps} training steps per shortened epoch; the step mix is this "
                  f"run's policies', not the study's learned ones)")
    return med


def start_from_policies(study: Path, jobs: list) -> None:
    """Every member starts its online phase from the policy the study's run of the same source and seed learned
    (``<study>/runs/<source>/seed<k>/policy.pt``: actor and normalisers), so that the epochs timed play the step
    mix of learned policies (mostly a held needle at the goal) instead of a fresh BC actor's. The critics start
    fresh: what an update costs does not depend on the weights."""
    import torch

    from surrol_data.algos.ensemble import EnsembleDDPG

    paths = [study / "runs" / Path(cfg.run_dir).parent.name / Path(cfg.run_dir).name / "policy.pt" for cfg in jobs]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        sys.exit(f"--actors-from {study}: no learned policy at {', '.join(missing)}")
    saved = [torch.load(p, map_location="cpu", weights_only=True) for p in paths]
    finish = EnsembleDDPG.finish_pretraining

    def load_then_finish(self) -> None:
        for i, ckpt in enumerate(saved):
            self.actor.load_member_state(i, ckpt["actor"])
            self.inputs[i].obs_norm.load_state_dict(ckpt["obs_norm"])
            self.inputs[i].goal_norm.load_state_dict(ckpt["goal_norm"])
        finish(self)

    EnsembleDDPG.finish_pretraining = load_then_finish


def run_groups(folder: Path) -> dict[str, list[Path]]:
    """The run folders under ``folder`` by demo source: a study's (``runs/<source>/seed<k>/``), one source's
    (``<source>/seed<k>/``, e.g. ``docs/results/table1/runs/expert``), or a folder of sources' folders."""
    if (folder / "runs").is_dir():
        folder = folder / "runs"
    direct = sorted(p.parent for p in folder.glob("*/metrics.jsonl"))
    if direct:
        return {folder.name: direct}
    groups = {}
    for p in sorted(folder.glob("*/*/metrics.jsonl")):
        groups.setdefault(p.parent.parent.name, []).append(p.parent)
    return groups


def compare_learning(a: Path, b: Path, epochs: list[int], console: Console) -> bool:
    """Success at ``epochs`` of the runs under ``a`` (before) and ``b`` (after), per demo source: mean ± std over
    seeds with the bootstrap 95 % interval of the mean (the study report's); the two agree where each mean lies
    within the other's interval. Returns whether they agree everywhere (a source or epoch missing on one side
    does not)."""
    from surrol_data.algos.train import read_metrics
    from surrol_data.evaluation.metrics import estimate

    groups = {side: run_groups(folder) for side, folder in (("A", a), ("B", b))}
    for side, folder in (("A", a), ("B", b)):
        if not groups[side]:
            sys.exit(f"--compare-learning: no run folders (<source>/seed<k>/metrics.jsonl) under {folder}")
    if len(groups["A"]) == 1 and len(groups["B"]) == 1:   # one source each: compare them whatever their names
        label = " vs ".join(dict.fromkeys(next(iter(g)) for g in groups.values()))
        groups = {side: {label: next(iter(g.values()))} for side, g in groups.items()}
    table = Table(title=f"learning before (A: {a}) and after (B: {b}): success rate, mean ± std over seeds "
                        f"[bootstrap 95 % interval]")
    for col in ("source", "epoch", "A", "B", "within each other's interval"):
        table.add_column(col, justify="left" if col == "source" else "right")
    agree = True
    for source in sorted(set(groups["A"]) | set(groups["B"])):
        runs = {side: groups[side].get(source, []) for side in ("A", "B")}
        rows = {side: [{r["epoch"]: r["success_rate"] for r in read_metrics(d)} for d in runs[side]]
                for side in runs}
        for epoch in epochs:
            est, cells = {}, {}
            for side in ("A", "B"):
                values = [r[epoch] for r in rows[side] if epoch in r]
                est[side] = estimate(values) if values else None
                e = est[side]
                cells[side] = ("-" if e is None else
                               f"{e.mean:.3f} ± {e.std:.3f} [{e.ci_low:.3f}, {e.ci_high:.3f}] ({e.n} seeds)")
            ea, eb = est["A"], est["B"]
            ok = (ea is not None and eb is not None and ea.n > 1 and eb.n > 1
                  and eb.ci_low <= ea.mean <= eb.ci_high and ea.ci_low <= eb.mean <= ea.ci_high)
            agree &= ok
            table.add_row(source, str(epoch), cells["A"], cells["B"], "yes" if ok else "NO")
    console.print(table)
    return agree


def paper_protocol(args, console: Console) -> None:
    import resource

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
    shorten = [f"experiment.cycles={args.cycles}"] if args.cycles else []
    shorten += [f"algo.offline_steps={args.offline_steps}"] if args.offline_steps is not None else []
    jobs = []
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        full = to_train_config(compose("config", overrides=["algo=ddpgbc", "task=NeedlePick", "experiment=paper",
                                                            f"demos.path={script}", "run_dir=unused"]))
        for source, path in sources.items():
            for seed in args.paper_seeds:
                demos = source if path != script else "script"
                overrides = ["algo=ddpgbc", "task=NeedlePick", f"demos={demos}", "experiment=paper",
                             f"demos.path={path}", f"experiment.epochs={args.epochs}", f"seed={seed}",
                             f"run_dir={out / source / f'seed{seed}'}", "tensorboard=false", "progress=false",
                             "overwrite=true", *shorten, *args.overrides]
                jobs.append(to_train_config(compose("config", overrides=overrides)))
        baseline = to_train_config(compose("config", overrides=[
            "algo=ddpgbc", "task=NeedlePick", "demos=script", "experiment=paper", f"demos.path={script}",
            f"experiment.epochs={args.baseline_epochs}", "seed=0", f"run_dir={out / 'single'}", "overwrite=true",
            "tensorboard=false", "progress=false", *shorten, *args.overrides]))
    cfg0, m = jobs[0], len(jobs)
    hidden = list(cfg0.learner_params.get("hidden_sizes", [256, 256, 256]))
    flops = update_flops(19, 3, 5, hidden, int(cfg0.learner_params["batch_size"]),
                         int(cfg0.learner_params["demo_batch_size"]), bool(cfg0.learner_params["q_filter"]))
    peak = matmul_peak_gflops(m, int(cfg0.learner_params["batch_size"]), hidden[0])
    console.print(f"{m} runs, {flops / 1e9:.2f} GFLOP per run-update, matmul peak {peak:.0f} GFLOP/s in CPU time "
                  f"(1 thread, ({m}, 128, {hidden[0]}) x ({hidden[0]}, {hidden[0]}) bmm)"
                  + (f"; {', '.join(substituted)} demos replaced by script demos (no NeedlePick_human)" if substituted else ""))
    full_epochs, s_full = 100, full.schedule
    if not args.no_floor:
        compute_floor(console, full, m, flops, peak, full_epochs)

    if args.threads_ab:
        threads_ab(console, jobs, args)
        return
    if args.actors_from:
        start_from_policies(args.actors_from, jobs)
    cpu0, kids0, t0 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    import inspect

    nice = {"worker_nice": args.worker_nice} if "worker_nice" in inspect.signature(train_batched).parameters else {}
    runs = train_batched(jobs, overlap=not args.no_overlap, n_workers=cfg0.schedule.n_envs, progress=True, **nice)
    batched_wall = time.perf_counter() - t0
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    learner_cpu, envs_cpu = time.process_time() - cpu0, (kids.ru_utime + kids.ru_stime) - (kids0.ru_utime + kids0.ru_stime)
    t0 = time.perf_counter()
    single_rows = train(baseline) if args.baseline_epochs > 0 else []
    single_wall = time.perf_counter() - t0

    rows, s = runs[0], cfg0.schedule
    scale = s_full.cycles / s.cycles   # a shortened epoch's collection and updates, scaled to the protocol's
    table = Table(title=f"paper protocol, {m} runs as one batched ensemble (overlap={not args.no_overlap}, "
                        f"worker nice {args.worker_nice}, "
                        f"{s.cycles} of {s_full.cycles} cycles per epoch)")
    for c in ("epoch", "collect s", "update s", "eval s", "epoch s", "learner CPU s", "envs CPU s", "cores busy",
              "env steps/s", "run-updates/s", "GFLOP/s", "of peak", "success (min/median/max)"):
        table.add_column(c, justify="right")
    prev_wall = 0.0
    per_epoch = []
    for e, r in enumerate(rows):
        wall = r["wall_s"] - prev_wall
        prev_wall = r["wall_s"]
        succ = sorted(run[e]["success_rate"] for run in runs)
        cpu_l, cpu_e = r.get("time_cpu_learner_s"), r.get("time_cpu_envs_s")
        busy = "-" if cpu_l is None else f"{(cpu_l + cpu_e) / wall:.2f} of {os.cpu_count()}"
        cpus = ("-", "-") if cpu_l is None else (f"{cpu_l:.1f}", f"{cpu_e:.1f}")
        success = f"{succ[0]:.2f}/{statistics.median(succ):.2f}/{succ[-1]:.2f}"
        if r["epoch"] == 0:
            table.add_row("0 (BC)", "-", "-", f"{r['time_eval_s']:.1f}", f"{wall:.1f}", *cpus, busy, "-", "-", "-", "-",
                          success)
            continue
        steps = m * (r["env_steps"] - rows[e - 1]["env_steps"]) + m * s.eval_episodes * s.max_episode_steps
        updates = m * (r["updates"] - rows[e - 1]["updates"])
        gflops = updates * flops / r["time_update_s"] / 1e9 if r["time_update_s"] else float("nan")
        per_epoch.append((r["time_collect_s"], r["time_update_s"], r["time_eval_s"], wall - r["time_collect_s"]
                          - r["time_update_s"] - r["time_eval_s"]))
        table.add_row(str(r["epoch"]), f"{r['time_collect_s']:.1f}", f"{r['time_update_s']:.1f}",
                      f"{r['time_eval_s']:.1f}", f"{wall:.1f}", *cpus, busy, f"{steps / wall:.0f}",
                      f"{updates / r['time_update_s']:.0f}", f"{gflops:.0f}", f"{gflops / peak:.0%}", success)
    console.print(table)
    console.print(f"whole timed training (setup and {len(rows)} epochs incl. epoch 0): {batched_wall:.0f} s wall, learner "
                  f"{learner_cpu:.0f} CPU s, env workers {envs_cpu:.0f} CPU s (as reaped) -> "
                  f"{(learner_cpu + envs_cpu) / batched_wall:.2f} of {os.cpu_count()} cores busy")
    if per_epoch:
        collect, update, evals, other = (statistics.median(x) for x in zip(*per_epoch))
        epoch_full = scale * (collect + update) + evals + other
        console.print(f"median epoch: collect {collect:.1f} s + update {update:.1f} s (x{scale:g} for the protocol's "
                      f"{s_full.cycles} cycles) + eval {evals:.1f} s + other {other:.1f} s -> {epoch_full:.1f} s per "
                      f"protocol epoch; EXTRAPOLATED full study ({m} runs x {full_epochs} epochs, offline phase "
                      f"excluded): {full_epochs * epoch_full / 3600:.2f} h")
    timed = [(r, p) for p, r in zip(rows, rows[1:]) if "time_cpu_envs_s" in r]
    if timed:
        # the cores' work per protocol epoch, from CPU seconds (valid on a shared machine, where wall time is not):
        # env CPU per env step x the protocol's steps; learner CPU scaled with the updates
        env_step_cpu = statistics.median([r["time_cpu_envs_s"] / (m * (r["env_steps"] - p["env_steps"])
                                          + m * s.eval_episodes * s.max_episode_steps) for r, p in timed])
        learner = statistics.median([r["time_cpu_learner_s"] for r, _ in timed]) * scale
        envs = env_step_cpu * m * (s_full.cycles * s_full.episodes_per_cycle + s_full.eval_episodes) * s_full.max_episode_steps
        cores = os.cpu_count() or 1
        # an epoch's phases on a quiet machine: cycles 1..C-1 overlap the learner (one thread, the workers
        # niced) with the workers' episodes; the last cycle's updates run alone; evaluation is envs only
        c = s_full.cycles
        env_eval = env_step_cpu * m * s_full.eval_episodes * s_full.max_episode_steps
        env_train = envs - env_eval
        lo, eo = learner * (c - 1) / c, env_train * (c - 1) / c
        if args.worker_nice > 0:   # the learner keeps a core, the workers share what is left
            overlapped = max(lo, (lo + eo) / cores)
        else:   # learner and n workers share the cores equally until one side is done
            share = cores / (cfg0.schedule.n_envs + 1)
            t_workers = eo / cfg0.schedule.n_envs / share
            t_learner = lo / share
            overlapped = (t_workers + lo - share * t_workers if t_workers < t_learner
                          else t_learner + (eo - share * cfg0.schedule.n_envs * t_learner) / cores)
        epoch_phases = overlapped + learner / c + env_train / c / cores + env_eval / cores
        epoch_ideal = max(learner, (learner + envs) / cores)
        console.print(f"CPU per protocol epoch: learner {learner:.0f} s (one thread), env workers {envs:.0f} s "
                      f"({env_step_cpu * 1e3:.2f} ms per env step). PROJECTED full study on a quiet machine "
                      f"({m} runs x {full_epochs} epochs): {full_epochs * epoch_phases / 3600:.2f} h with this path's "
                      f"phases ({epoch_phases:.0f} s per epoch); {full_epochs * epoch_ideal / 3600:.2f} h if all "
                      f"{cores} cores were busy all the time")
    phased = [(r, p) for r, p in timed if "time_cpu_envs_eval_s" in r and "time_cpu_learner_update_s" in r]
    if phased:
        cpu_breakdown(console, phased, m, s, s_full, full_epochs)
    if single_rows:
        online = [r for r in single_rows if r["epoch"] > 0]
        walls = [b["wall_s"] - a["wall_s"] for a, b in zip(single_rows, single_rows[1:])]
        c, u = statistics.median([r["time_collect_s"] for r in online]), statistics.median([r["time_update_s"] for r in online])
        other = statistics.median(walls) - c - u
        per_epoch_single = scale * (c + u) + other
        ups = statistics.median([r["updates"] - p["updates"] for p, r in zip(single_rows, single_rows[1:])]) / u
        console.print(f"baseline, single-run path (same run, {args.baseline_epochs} epoch(s) of 1 run): "
                      f"{per_epoch_single:.1f} s per protocol epoch, {ups:.0f} updates/s ({ups * flops / 1e9:.0f} GFLOP/s); "
                      f"EXTRAPOLATED {m} runs x {full_epochs} epochs one after another: "
                      f"{m * full_epochs * per_epoch_single / 3600:.2f} h")
        if per_epoch:
            console.print(f"batched / serial single runs, per epoch of all {m} runs: {epoch_full / (m * per_epoch_single):.2f}x "
                          f"the time ({m * per_epoch_single / epoch_full:.1f}x faster); the single-run baseline took "
                          f"{single_wall:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--protocol", choices=("reference", "paper"), default="reference",
                        help="paper: time the 12-run paper study on the batched path (see above)")
    parser.add_argument("--epochs", type=int, default=3, help="--protocol paper: epochs to time")
    parser.add_argument("--paper-seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    parser.add_argument("--baseline-epochs", type=int, default=1, help="--protocol paper: single-run epochs to time")
    parser.add_argument("--no-overlap", action="store_true", help="--protocol paper: serial collect-then-update")
    parser.add_argument("--cycles", type=int, default=None,
                        help="--protocol paper: cycles per epoch (shorter epochs; collection and updates are scaled "
                             "back to the protocol's 20 in the extrapolation)")
    parser.add_argument("--offline-steps", type=int, default=None, help="--protocol paper: BC pre-training steps")
    parser.add_argument("--worker-nice", type=int, default=0, help="--protocol paper: the env workers' niceness")
    parser.add_argument("--no-floor", action="store_true", help="--protocol paper: skip the compute-floor table")
    parser.add_argument("--actors-from", type=Path,
                        help="--protocol paper: start every run from the policy this study's run of the same source "
                             "and seed learned (e.g. docs/results/table1): time the step mix of learned policies")
    parser.add_argument("--threads-ab", action="store_true",
                        help="--protocol paper: only compare the learner at fixed threads with widening to idle cores")
    parser.add_argument("--ab-rounds", type=int, default=2, help="--threads-ab: rounds of A then B")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "train_speed")
    parser.add_argument("--demos", type=Path, default=REPO / "datasets" / "NeedlePick_script")
    parser.add_argument("--runs", type=Path, nargs="*", help="summarise these finished run folders instead of training")
    parser.add_argument("--study", type=Path, help="--protocol paper: the cost of this study's finished runs "
                                                   "(e.g. docs/results/table1) instead of training")
    parser.add_argument("--cores", type=int, default=2, help="--study: cores for the projected study time")
    parser.add_argument("--compare-learning", type=Path, nargs=2, metavar=("RUNS_A", "RUNS_B"),
                        help="compare the success of two sets of runs (a study folder, or one source's seed folders) "
                             "at --at epochs; exit 1 unless each mean lies within the other's bootstrap interval")
    parser.add_argument("--at", type=int, nargs="+", default=[50, 100], help="--compare-learning: epochs")
    args, overrides = parser.parse_known_args()
    overrides = [o for o in overrides if o != "--"]
    args.overrides = overrides
    console = Console(width=160)
    if args.compare_learning:
        sys.exit(0 if compare_learning(*args.compare_learning, args.at, console) else 1)
    if args.protocol == "paper" and args.study:
        study_cost(args.study, console, args.cores)
        return
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

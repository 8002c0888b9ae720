"""Dataset commands at scale: `info`, `validate`, `filter` and `split` on an N-episode dataset.

Usage: ``uv run python benchmarks/dataset_scale.py [--episodes 10000] [--steps 33] [--keep DIR] [--json FILE]
[--info-only]``

The dataset is built cheaply but for real: synthesised NeedlePick-shaped state-only episodes (19-D state, 3-D
goals, 5-D actions, ``--steps`` frames, the length of an oracle NeedlePick episode) written by the real
:class:`~surrol_data.datasets.recorder.DatasetRecorder` (journal, checkpoints, seals: the files a collection writes),
with provenance spread over two skills and four operators so that ``filter`` and ``split`` have groups to pick.
Then each command runs once as the real ``surrol-data`` CLI in a fresh process (its imports included) and is timed
from outside: ``info`` on the fresh dataset (its input check included: the metadata checks, no frame read),
``validate --no-reward`` (the synthesised rewards are not the task's, so the reward check, which replays the task's
reward function, is left out; LeRobot's own load is included), ``info`` again (the same bytes: the answer remembered
by content digest, :mod:`surrol_data.datasets.info_cache`),
``filter --where`` keeping half (the frame checks of its input included: the first command after ``validate``
finds the verdict remembered), ``split``. Also the size of ``meta/episodes`` per episode. Targets (issue 30):
info ≤ 5 s; validate, filter and split ≥ 200 episodes/s.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_DISABLE_PROGRESS_BARS", "1")

REPO_ROOT = Path(__file__).resolve().parents[1]
INFO_TARGET_S, RATE_TARGET = 5.0, 200.0
SKILLS, OPERATORS = ("expert", "novice"), ("e1", "e2", "n1", "n2")


def build(root: Path, episodes: int, steps: int) -> float:
    """Write ``episodes`` synthesised episodes with the real recorder; seconds it took."""
    from dataset_io import ACT_DIM, GOAL_DIM, OBS_DIM, synthetic_episode
    from tqdm import tqdm

    from surrol_data.datasets.recorder import DatasetRecorder
    from surrol_data.datasets.schema import frame_features

    t0 = time.perf_counter()
    with DatasetRecorder(root, features=frame_features(OBS_DIM, GOAL_DIM, ACT_DIM, 1), task="NeedlePick",
                         env_id="SurRoL/NeedlePick-v0", task_description="pick up the needle",
                         command="benchmarks/dataset_scale.py") as rec:
        for i in tqdm(range(episodes), desc=f"build {episodes} episodes", unit="ep"):
            rec.record(synthetic_episode(i, steps), {
                "source": "haptic", "device": "touch", "skill": SKILLS[i % 2], "operator_id": OPERATORS[i % 4],
                "seed": i})
    return time.perf_counter() - t0


def timed(args: list[str]) -> float:
    env = {**os.environ, "PYTHONPATH": f"{REPO_ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    t0 = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "surrol_data.cli", *args], capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    if result.returncode != 0:
        raise SystemExit(f"surrol-data {' '.join(args)} failed ({result.returncode}):\n{result.stdout[-2000:]}"
                         f"\n{result.stderr[-2000:]}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=33)
    parser.add_argument("--keep", type=Path, default=None, help="Build the dataset here and keep it (reused if it "
                                                                "exists with the right number of episodes).")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--info-only", action="store_true", help="Time `info` only: on the fresh dataset (an empty "
                                                                   "cache folder), then again.")
    args = parser.parse_args()

    from rich.console import Console
    from rich.table import Table

    tmp = Path(tempfile.mkdtemp(prefix="dataset_scale_"))
    root = args.keep or tmp / "ds"
    try:
        build_s = float("nan")
        existing = root / "meta" / "info.json"
        # the commands' own check remembers what passed (surrol_data.datasets.validated_cache): start from a fresh
        # memory, as after a collection
        os.environ["XDG_CACHE_HOME"] = str(tmp / "cache")
        if not (existing.exists() and json.loads(existing.read_text())["total_episodes"] == args.episodes):
            if root.exists():
                shutil.rmtree(root)
            build_s = build(root, args.episodes, args.steps)
        meta_bytes = sum(p.stat().st_size for p in (root / "meta" / "episodes").rglob("*.parquet"))
        n = args.episodes
        rows = [("info (first, on the fresh dataset)", timed(["info", str(root)]), None)]
        if args.info_only:   # the answer is remembered by content digest: the same bytes again
            rows.append(("info (again, the same bytes)", timed(["info", str(root)]), None))
        else:
            rows += [
                ("validate --no-reward", timed(["validate", str(root), "--no-reward"]), n),
                ("info (again)", timed(["info", str(root)]), None),
                ("filter --where 'skill == \"expert\"'", timed(["filter", str(root), "--out", str(tmp / "expert"),
                                                                 "--where", 'skill == "expert"']), n),
                ("split", timed(["split", str(root), "--out", str(tmp / "split")]), n),
            ]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    table = Table(title=f"{n} episodes × {args.steps} frames ({os.cpu_count()} CPUs), one run each")
    for col in ("command", "seconds", "episodes/s", "target"):
        table.add_column(col, justify="left" if col == "command" else "right")
    for name, seconds, count in rows:
        table.add_row(name, f"{seconds:.1f}", f"{count / seconds:.0f}" if count else "",
                      f"≤ {INFO_TARGET_S:.0f} s" if count is None else f"≥ {RATE_TARGET:.0f}/s")
    console = Console()
    console.print(table)
    console.print(f"built in {build_s:.0f} s; meta/episodes: {meta_bytes / n / 1024:.1f} KB per episode")
    if args.json:
        args.json.write_text(json.dumps({"episodes": n, "steps": args.steps, "build_s": build_s,
                                         "meta_episodes_bytes_per_episode": meta_bytes / n,
                                         "seconds": {name: s for name, s, _ in rows}}, indent=2))


if __name__ == "__main__":
    main()

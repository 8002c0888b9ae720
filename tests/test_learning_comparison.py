"""`benchmarks/train_speed.py --compare-learning RUNS_A RUNS_B`: the before/after learning comparison of a speed
change (success at the report epochs of seeds trained before and after, each mean within the other's bootstrap
interval), on real tiny runs."""

import io
import json
import shutil
import sys
from pathlib import Path

import torch
from rich.console import Console

from surrol_data.algos.demos import DemoSpec
from surrol_data.algos.train import Schedule, TrainConfig
from surrol_data.algos.train_batched import train_batched

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from train_speed import compare_learning  # noqa: E402


def _train(folder: Path, seeds, epochs: int) -> None:
    cfgs = [TrainConfig(env_id="SurRoL/NeedleReach-v0", run_dir=str(folder / f"seed{s}"), learner="ddpg",
                        learner_params={"hidden_sizes": (16, 16)}, demos=DemoSpec(path=None),
                        schedule=Schedule(epochs=epochs, cycles=1, episodes_per_cycle=1, updates_per_cycle=2,
                                          n_envs=1, eval_episodes=2, buffer_episodes=10, max_episode_steps=10),
                        seed=s, progress=False, tensorboard=False) for s in seeds]
    before = torch.get_num_threads()
    try:
        train_batched(cfgs, overlap=False, n_workers=0, progress=False)
    finally:
        torch.set_num_threads(before)


def _compare(a: Path, b: Path, *at: int) -> tuple[bool, str]:
    """What ``train_speed.py --compare-learning a b --at ...`` decides (its exit status: 0 when True) and prints."""
    out = io.StringIO()
    agree = compare_learning(a, b, list(at), Console(file=out, width=200))
    return agree, out.getvalue()


def _set_success(run: Path, epoch: int, value: float) -> None:
    path = run / "metrics.jsonl"
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    for r in rows:
        if r["epoch"] == epoch:
            r["success_rate"] = value
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_compare_learning_passes_equal_runs_and_fails_moved_or_missing_ones(tmp_path):
    before, after = tmp_path / "before" / "expert", tmp_path / "after" / "expert"
    _train(before, (0, 1, 2), epochs=2)
    _train(after, (0, 1, 2), epochs=1)
    # the same code and seeds: the same curves, within each other's intervals at every epoch both have
    agree, text = _compare(before, after, 0, 1)
    assert agree and "yes" in text and "NO" not in text, text
    # an epoch one side never reached is no agreement
    agree, text = _compare(before, after, 1, 2)
    assert not agree and "NO" in text
    # success moved out of the other's interval: every seed at 1.0 after, at 0.0 before
    moved = tmp_path / "moved" / "expert"
    shutil.copytree(after, moved)
    for k in range(3):
        _set_success(before / f"seed{k}", 1, 0.0)
        _set_success(moved / f"seed{k}", 1, [1.0, 0.9, 0.8][k])
    agree, text = _compare(before, moved, 1)
    assert not agree and "NO" in text, text
    # a study folder (runs/<source>/seed<k>) is read per source
    study = tmp_path / "study"
    shutil.copytree(tmp_path / "after", study / "runs")
    agree, text = _compare(study, tmp_path / "after", 0, 1)
    assert agree and "expert" in text, text

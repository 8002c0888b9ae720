"""Fingerprint of the envs' behaviour: a hash of every observation, reward and info of seeded episodes.

Usage: ``uv run python benchmarks/env_fingerprint.py [--tasks ...] [--episodes 2] [--save FILE | --check FILE]``

Speed work must not change what the envs do: record the fingerprints before a change (``--save``), then check
that the change keeps every one identical (``--check``; exit status 1 and the differing tasks otherwise). Per
task, one env runs ``episodes`` oracle episodes then ``episodes`` episodes of seeded uniform random actions
back to back (so state left over from an earlier episode would show), each episode reset with its own seed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.progress import track
from rich.table import Table

import surrol_data.envs
from surrol_data.envs import env_id


def _feed(h, value) -> None:
    if isinstance(value, dict):
        for key in sorted(value):
            h.update(str(key).encode())
            _feed(h, value[key])
    elif isinstance(value, (list, tuple)):
        for v in value:
            _feed(h, v)
    else:
        a = np.asarray(value)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())


def fingerprint(task: str, episodes: int = 2) -> str:
    """Hex digest over every (obs, reward, terminated, truncated, info) of the task's seeded episodes."""
    env = gym.make(env_id(task))
    h = hashlib.sha256()
    oracle = env.unwrapped.oracle_action
    for policy in ("oracle", "random"):
        for seed in range(episodes):
            rng = np.random.default_rng(1000 + seed)
            obs, info = env.reset(seed=seed)
            _feed(h, (obs, info))
            done = False
            while not done:
                if policy == "oracle":
                    action = oracle(obs)
                else:
                    action = rng.uniform(-1.0, 1.0, env.action_space.shape).astype(np.float32)
                obs, reward, terminated, truncated, info = env.step(action)
                _feed(h, (obs, reward, terminated, truncated, info))
                done = terminated or truncated
    env.close()
    return h.hexdigest()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(surrol_data.envs.TASKS))
    parser.add_argument("--episodes", type=int, default=2, help="oracle and random episodes each, per task")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--save", type=Path, help="write the fingerprints to this JSON file")
    group.add_argument("--check", type=Path, help="compare with fingerprints saved by --save")
    args = parser.parse_args()

    expected = json.loads(args.check.read_text()) if args.check else {}
    if expected and expected.get("episodes") != args.episodes:
        sys.exit(f"{args.check} was saved with --episodes {expected.get('episodes')}; check with the same count")
    got = {task: fingerprint(task, args.episodes) for task in track(args.tasks, description="fingerprinting")}
    table = Table(title=f"env fingerprints ({args.episodes} oracle + {args.episodes} random episodes per task)")
    for col in ("task", "sha256", "saved"):
        table.add_column(col)
    differ = []
    for task, digest in got.items():
        saved = expected.get("tasks", {}).get(task)
        verdict = "—" if saved is None else ("same" if saved == digest else "DIFFERENT")
        if saved is not None and saved != digest:
            differ.append(task)
        table.add_row(task, digest[:16], verdict)
    Console(width=120).print(table)
    if args.save:
        args.save.write_text(json.dumps({"episodes": args.episodes, "tasks": got}, indent=1))
    if differ:
        sys.exit(f"behaviour changed on: {', '.join(differ)}")


if __name__ == "__main__":
    main()

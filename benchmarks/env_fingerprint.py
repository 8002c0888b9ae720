"""Fingerprint of the envs' behaviour: a hash of every observation, reward and info of seeded episodes.

Usage: ``uv run python benchmarks/env_fingerprint.py [--tasks ...] [--episodes 2] [--save FILE | --check FILE]``

Speed work must not change what the envs do: record the fingerprints before a change (``--save``), then check
that the change keeps every one identical (``--check``; exit status 1 and the differing tasks otherwise). Per
task, one env runs ``episodes`` oracle episodes then ``episodes`` episodes of seeded uniform random actions
back to back (so state left over from an earlier episode would show), each episode reset with its own seed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rich.console import Console
from rich.progress import track
from rich.table import Table

import surrol_data.envs
from surrol_data.envs.fingerprint import env_fingerprint


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
    got = {task: env_fingerprint(task, args.episodes) for task in track(args.tasks, description="fingerprinting")}
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

"""Demo sources for the Table I study: build the NeedlePick demo sets and print their quality beside the paper's.

    python benchmarks/demo_sources.py --task PegTransfer --horizon 300   # another task: sources matched to one another

    python benchmarks/demo_sources.py                       # matched sets: 100 script, 4 × 25 novice, 4 × 25 expert
    python benchmarks/demo_sources.py --natural             # the operators' and the oracle's own pace
    python benchmarks/demo_sources.py --episodes 20 --operators 4   # a quicker look

The sets are built exactly as ``surrol-data study table1`` builds them (:func:`surrol_data.study.build_demo_sets`,
a 150-step horizon unless ``--horizon``) into ``--out`` (kept, and continued on a rerun), then scored by the assessment of
``surrol-data assess`` (:mod:`surrol_data.evaluation.assess`). The table: per source, mean steps to complete and
tool-tip path over successful episodes beside the paper's (expert 113 / 12.1 cm, novice 117 / 12.5 cm, script
109 / 11.7 cm) and whether both are within ±10 %; then where skill shows: smoothness (SPARC and LDLJ from the
device trace), idle time, failed grasps, jaw closures, clutch uses, and the share of attempts kept. The same
table goes to ``--out``/demos.md. Exits 1 when a matched set misses the ±10 % band.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console
from rich.markdown import Markdown

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--natural", action="store_true", help="unmatched sets (the operators' own pace)")
    parser.add_argument("--episodes", type=int, default=100, help="demos per source")
    parser.add_argument("--operators", type=int, default=4, help="simulated operators per skill")
    parser.add_argument("--task", default="NeedlePick",
                        help="the paper's NeedlePick (matched to its demo sets), or another task (matched to one another)")
    parser.add_argument("--horizon", type=int, default=150, help="demo episode horizon (steps)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for the datasets (default runs/demo_sources/matched or natural)")
    parser.add_argument("--ship", action="store_true",
                        help="build the sets to ship into --out (packed, with the manifest of their hashes), as "
                             "`surrol-data study table1 --build-demos` does: e.g. --out datasets/table1_v2")
    args = parser.parse_args()

    from surrol_data.study import StudySpec, build_demo_sets, demo_quality, demo_quality_markdown
    from surrol_data.study.demo_sets import build_shipped_demo_sets

    kind = "natural" if args.natural else "matched"
    out = args.out or REPO / "runs" / "demo_sources" / (kind if args.task == "NeedlePick" else f"{args.task}_{kind}")
    spec = StudySpec(experiment="table1", task=args.task, episodes=args.episodes, operators=args.operators,
                     horizon=args.horizon, matched=not args.natural)
    console = Console(width=180)
    console.print(f"building {kind} demo sets in {out} ({args.episodes} per source, {args.operators} operators per "
                  f"skill, {args.horizon}-step horizon)")
    if args.ship and args.out is None:
        parser.error("--ship needs --out (the folder the sets are shipped in, e.g. datasets/table1_v2)")
    rows = demo_quality((build_shipped_demo_sets if args.ship else build_demo_sets)(out, spec), args.task)
    against = "the paper's" if args.task == "NeedlePick" else "one another"
    markdown = (f"# {args.task} demo sources ({kind}) beside {against}\n\n"
                f"{demo_quality_markdown(rows, not args.natural, args.task)}")
    console.print(Markdown(markdown))
    (out / "demos.md").write_text(markdown)
    console.print(f"wrote {out / 'demos.md'}")
    missed = [r["source"] for r in rows if r["matched"] != "yes"]
    if missed and not args.natural:
        reference = "the paper's demo sets" if args.task == "NeedlePick" else "the sources' mean"
        console.print(f"[red]not within ±10 % of {reference}: {', '.join(missed)}[/]")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

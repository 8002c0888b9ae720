"""Merge speed with video: lerobot's aggregate_datasets (``surrol-data merge``) vs. re-recording every episode.

Usage: ``uv run python benchmarks/merge_speed.py [--episodes 20] [--camera-size 128x128] [--repeats 3] [--work DIR]``

Two camera datasets of ``--episodes`` scripted NeedleReach episodes each (endoscope video, recorded with
``collect_script(camera_size=...)``, kept in ``--work`` between runs) are merged, in this one process, by

* ``re-record, LeRobotDataset decode``: the merge before this change — every episode read back, its frames
  decoded item by item through ``LeRobotDataset`` and written again through ``DatasetRecorder`` (video
  re-encoded); the baseline of the ratios;
* ``re-record, PyAV decode``: the same with the reader's own PyAV decoder — what ``filter``/``split`` do now;
* ``aggregate_datasets``: ``merge_datasets`` — our checks, lerobot's ``aggregate_datasets`` (parquet copied, video
  concatenated without re-encoding), traces, sidecar and card.

Each method runs ``--repeats`` times in alternation; the table gives medians and the ratio against re-record.
Both outputs are then checked: every provenance column equal to the inputs', and ``validate`` (all checks,
LeRobot's reader included) finds no problem.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

TASK = "NeedleReach"


def build_inputs(work: Path, episodes: int, camera_size: tuple[int, int], console: Console) -> list[Path]:
    from surrol_data.collect.script_source import collect_script
    from surrol_data.datasets.reader import DatasetReader

    roots = []
    for i in range(2):
        root = work / f"input_{i}_{episodes}ep_{camera_size[0]}x{camera_size[1]}"
        if not (root.exists() and len(DatasetReader(root)) == episodes):
            shutil.rmtree(root, ignore_errors=True)
            console.print(f"recording {root.name} ...")
            collect_script(TASK, episodes, root, seed=1000 * i, camera_size=camera_size, progress=False)
        roots.append(root)
    return roots


def re_record_lerobot_decode(inputs: list[Path], out: Path) -> None:
    """The merge before this change, as it was: frames decoded item by item through ``LeRobotDataset`` (pyav
    backend), then re-recorded. Reproduced here by giving the reader that decoder for the run."""
    import numpy as np

    from surrol_data.datasets.writer import VIDEO_BACKEND, _lerobot_dataset_class
    from surrol_data.datasets.hub_offline import hub_offline
    from surrol_data.datasets.reader import DatasetReader

    original = DatasetReader.trajectory
    opened: dict[Path, object] = {}

    def trajectory_via_lerobot(self, ep, images=False):
        traj = original(self, ep)
        if not images or not self.cameras:
            return traj
        if self.root not in opened:
            with hub_offline():
                opened[self.root] = _lerobot_dataset_class()(f"local/{self.root.name}", root=self.root,
                                                             video_backend=VIDEO_BACKEND)
        ds = opened[self.root]
        row = ds.meta.episodes[int(ep)]
        frames = {cam: [] for cam in self.cameras}
        for i in range(int(row["dataset_from_index"]), int(row["dataset_to_index"])):
            item = ds[i]
            for cam in self.cameras:
                chw = item[f"observation.images.{cam}"].numpy()
                frames[cam].append(np.clip(np.rint(chw.transpose(1, 2, 0) * 255.0), 0, 255).astype(np.uint8))
        traj.images = {cam: np.stack(v + v[-1:]) for cam, v in frames.items()}
        return traj

    DatasetReader.trajectory = trajectory_via_lerobot
    try:
        re_record(inputs, out)
    finally:
        DatasetReader.trajectory = original


def re_record(inputs: list[Path], out: Path) -> None:
    from surrol_data.datasets.merge import copy_episodes
    from surrol_data.datasets.reader import DatasetReader

    copy_episodes([(root, DatasetReader(root).select()) for root in inputs], out, operation="merge", progress=False)


def aggregate(inputs: list[Path], out: Path) -> None:
    from surrol_data.datasets.merge import merge_datasets

    merge_datasets(out, inputs, progress=False)


def check(out: Path, inputs: list[Path]) -> str:
    """'ok', or what is wrong: provenance differing from the inputs', or validation problems."""
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.schema import PROVENANCE_COLUMNS
    from surrol_data.datasets.validate import validate_dataset

    expected = [row for root in inputs for row in DatasetReader(root).episodes.to_dict("records")]
    got = DatasetReader(out).episodes.to_dict("records")
    if len(got) != len(expected):
        return f"{len(got)} episodes, expected {len(expected)}"
    differ = sorted({k for a, b in zip(got, expected, strict=True) for k in PROVENANCE_COLUMNS
                     if a[k] != b[k] and not (a[k] != a[k] and b[k] != b[k])})
    problems = validate_dataset(out)
    if differ or problems:
        return f"provenance differs in {differ}; {len(problems)} problem(s): {problems[:2]}"
    return "ok"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--camera-size", default="128x128", help="WxH of the endoscope video")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "surrol_merge_speed")
    args = parser.parse_args()
    console = Console()
    w, h = (int(v) for v in args.camera_size.lower().split("x"))
    args.work.mkdir(parents=True, exist_ok=True)
    inputs = build_inputs(args.work, args.episodes, (w, h), console)
    import lerobot.datasets.aggregate  # noqa: F401  (imports paid before timing, for both methods)
    import lerobot.datasets.lerobot_dataset  # noqa: F401
    methods = {"re-record, LeRobotDataset decode (merge before)": re_record_lerobot_decode,
               "re-record, PyAV decode (filter/split now)": re_record,
               "aggregate_datasets (merge now)": aggregate}
    times: dict[str, list[float]] = {name: [] for name in methods}
    last: dict[str, Path] = {}
    for r in range(args.repeats):
        for name, merge in methods.items():
            out = args.work / f"out_{list(methods).index(name)}_{r}"
            shutil.rmtree(out, ignore_errors=True)
            t0 = time.perf_counter()
            merge(inputs, out)
            times[name].append(time.perf_counter() - t0)
            if name in last:
                shutil.rmtree(last[name], ignore_errors=True)
            last[name] = out
    baseline = statistics.median(times[next(iter(methods))])
    table = Table(title=f"merge of 2 x {args.episodes} {TASK} episodes with {w}x{h} endoscope video "
                        f"(median of {args.repeats})")
    for col in ("method", "median s", "runs s", "speed-up vs merge before", "output check"):
        table.add_column(col, justify="left" if col in ("method", "output check") else "right")
    for name in methods:
        med = statistics.median(times[name])
        table.add_row(name, f"{med:.2f}", ", ".join(f"{t:.2f}" for t in times[name]), f"{baseline / med:.1f}x",
                      check(last[name], inputs))
    console.print(table)


if __name__ == "__main__":
    main()

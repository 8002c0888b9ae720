"""A large scripted collection in shards: N datasets recorded at once (local worker processes, or SLURM jobs), each
with its own seeds, then merged into one dataset through ``merge`` (lerobot's ``aggregate_datasets``), provenance
kept.

    surrol-data collect --source script --task NeedlePick --num-episodes 1000 --shards 8 --out datasets/big
    surrol-data collect ... --shards 64 --launcher slurm --partition cpu     # one SLURM job per shard

Shard k of N records the seeds ``seed + k``, ``seed + k + N``, ``seed + k + 2N``, ... (attempt i uses
``seed + k + i·N``), so no two shards share a seed. An episode is a function of its task and seed, so each merged
episode is the one a single process records for that seed; when the oracle succeeds on every attempt the merged
dataset holds exactly one process's seeds ``seed .. seed + episodes - 1``. The shards stay in ``OUT.shards/``
(each a dataset of its own, with its command); running the same command again after a failed shard reuses the
finished shards and records the others anew.
"""

from __future__ import annotations

import os
import shutil
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

from tqdm.auto import tqdm

from surrol_data.collect.parallel_rollouts import exit_with
from surrol_data.collect.script_source import collect_script
from surrol_data.slurm import SlurmOptions, submit_array, wait_for


def shard_sizes(episodes: int, shards: int) -> list[int]:
    """Episodes per shard: as even as can be, the first ones one larger."""
    if shards < 1 or shards > episodes:
        raise ValueError(f"--shards must be between 1 and the number of episodes ({episodes}), got {shards}")
    return [episodes // shards + (k < episodes % shards) for k in range(shards)]


def shards_folder(out: Path) -> Path:
    return out.parent / f"{out.name}.shards"


def shard_root(out: Path, k: int, shards: int) -> Path:
    return shards_folder(out) / f"shard{k:03d}-of-{shards:03d}"


def _finished(root: Path, episodes: int) -> bool:
    """Whether ``root`` is a shard that recorded all its ``episodes`` and was closed properly."""
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.repair import is_unfinished

    if not (root / "meta" / "info.json").is_file() or is_unfinished(root):
        return False
    try:
        return len(DatasetReader(root).episodes) == episodes
    except Exception:  # noqa: BLE001  (anything unreadable is recorded again)
        return False


def record_shard(task: str, episodes: int, root: str, first_seed: int, stride: int, kwargs: dict) -> int:
    """One shard (a worker process or a SLURM job): ``episodes`` oracle episodes from ``first_seed`` by ``stride``."""
    return collect_script(task, episodes, root, seed=first_seed, seed_stride=stride, progress=False, **kwargs).kept


def collect_script_shards(task: str, episodes: int, out: str | Path, shards: int, *, seed: int = 0,
                          slurm: SlurmOptions | None = None, progress: bool = True, command: str | None = None,
                          say=print, **kwargs) -> Path:
    """Record ``episodes`` oracle episodes of ``task`` in ``shards`` shards (``slurm``: as SLURM jobs, else in
    local worker processes) and merge them into ``out``. ``kwargs`` go to :func:`collect_script` (max_steps,
    keep_failures, camera_size, speed)."""
    from surrol_data.datasets.merge import merge_datasets

    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} already exists: choose a new output folder (sharded collection does not "
                              "--append)")
    sizes = shard_sizes(episodes, shards)
    roots = [shard_root(out, k, shards) for k in range(shards)]
    todo = [k for k in range(shards) if not _finished(roots[k], sizes[k])]
    if len(todo) < shards:
        say(f"reusing {shards - len(todo)} finished shard(s) in {shards_folder(out)}")
    for k in todo:
        shutil.rmtree(roots[k], ignore_errors=True)   # a shard cut short is recorded anew (its seeds are fixed)
    kwargs = {**kwargs, "command": command}
    items = [(task, sizes[k], str(roots[k]), seed + k, shards, kwargs) for k in todo]
    if todo and slurm is not None:
        _on_slurm(items, out, slurm, say)
    elif todo:
        _locally(items, progress, say)
    failed = [roots[k].name for k in todo if not _finished(roots[k], sizes[k])]
    if failed:
        raise RuntimeError(f"shard(s) {', '.join(failed)} did not finish (see "
                           f"{shards_folder(out) / 'slurm' if slurm else 'the errors above'}); run the same command "
                           "again to record them (the finished shards are kept)")
    merge_datasets(out, roots, command=command, progress=progress)
    return out


def _locally(items: list[tuple], progress: bool, say) -> None:
    """One worker process per shard, at most one per core; a shard that fails is said and left for the check."""
    with ProcessPoolExecutor(max_workers=min(len(items), os.cpu_count() or 1), mp_context=get_context("spawn"),
                             initializer=exit_with, initargs=(os.getpid(),)) as pool:   # a killed parent ends them
        futures = {pool.submit(record_shard, *item): Path(item[2]).name for item in items}
        with tqdm(total=sum(item[1] for item in items), desc=f"collect {items[0][0]} (script, shards)", unit="ep",
                  disable=not progress) as bar:
            for future in as_completed(futures):
                try:
                    bar.update(future.result())
                except Exception as e:  # noqa: BLE001  (the other shards go on; the caller names the failed ones)
                    say(f"{futures[future]}: {e}")


def _on_slurm(items: list[tuple], out: Path, options: SlurmOptions, say) -> None:
    jobs = submit_array(record_shard, items, shards_folder(out) / "slurm",
                        f"collect-{items[0][0]}", options)
    say(f"submitted {len(jobs)} SLURM job(s), one per shard (logs: {shards_folder(out) / 'slurm'}/<job id>_0_log.out)")
    wait_for([j.job_id for j in jobs], say)

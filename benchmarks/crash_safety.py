"""Crash safety of every writer path, and validation against every damage class.

Usage: ``uv run python benchmarks/crash_safety.py [--trials 20] [--signal-trials 6] [--paths script merge ...]``,
``... --faults [--fault-sites 6]``, ``... --tmpfs``

Part 1 — kills. Each writer path runs the real ``surrol-data`` command (the typer app, in a child process
forked from this one after the heavy imports, so a trial costs seconds instead of the ~6 s lerobot import)
and is ended at a random moment of its run: ``--trials`` times by SIGKILL, ``--signal-trials`` times by
SIGTERM / SIGINT (alternating). The child reports every episode whose ``DatasetRecorder.record`` returned
(a pipe write right after it); that is the ground truth of "finished". Then, in this process, each output
goes through what our commands do first (:func:`surrol_data.datasets.guard.ensure_finished`: the automatic
repair), and is opened with our reader and with ``LeRobotDataset`` (first and last frame read). Per path:
trials, finished episodes, episodes lost (finished but not in the dataset; the episode in progress is not
counted), datasets that open, automatic repairs, device traces present (haptic paths), datasets that pass
``validate`` afterwards. A kill before the first episode leaves either no folder or one that a retry replaces:
that counts as "opens".

Part 2 — validation fuzz: every class of :mod:`surrol_data.collect.corruptions` applied to a copy of a good
dataset (camera video, device traces, two data files); ``validate_dataset`` must detect each (never raise,
never pass it), and the commands' own guard (:func:`surrol_data.datasets.guard.require_valid`) must refuse or
repair it.

Part 3 — ``--faults``: every write site of every writing path failed on purpose (:func:`fault_campaign`;
``--fault-sites N`` samples N sites per path, the default is every site × ENOSPC, EIO and EROFS).

Part 4 — ``--tmpfs``: every writing path run on a real tmpfs too small for it, then enlarged (:func:`tmpfs_campaign`;
root, in a mount namespace of its own).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import random
import shutil
import signal
import statistics
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_DISABLE_PROGRESS_BARS", "1")
os.environ.setdefault("SVT_LOG", "1")

# The heavy imports start helper threads; each forked trial only runs our own code, which starts none first.
warnings.filterwarnings("ignore", message=".*fork.*", category=DeprecationWarning)
warnings.filterwarnings("ignore", message="Cannot enable progress bars")

from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

TASK = "NeedleReach"
PATHS = ("script", "haptic-operator", "haptic-replay", "intervene-operator", "append", "merge", "filter", "split",
         "export")
HAPTIC = ("haptic-operator", "haptic-replay", "intervene-operator")


@dataclass
class Trial:
    path: str
    sig: str
    out: Path
    delay: float
    finished: dict = field(default_factory=dict)   # output root -> episodes whose record() returned
    exit_code: int | None = None
    base_episodes: int = 0


def _command(path: str, out: Path, bases: dict, episodes: int) -> list[str]:
    s, h, p = str(bases["script"]), str(bases["haptic"]), str(bases["policy"])
    return {
        "script": ["collect", "--source", "script", "--task", TASK, "--num-episodes", str(episodes), "--out", str(out)],
        "haptic-operator": ["collect", "--source", "haptic", "--device", "operator", "--skill", "expert",
                            "--operator-id", "e1", "--task", TASK, "--num-episodes", str(episodes), "--out", str(out)],
        "haptic-replay": ["collect", "--source", "haptic", "--device", "replay", "--trace", h, "--task", TASK,
                          "--num-episodes", str(episodes), "--out", str(out)],
        # A policy that never moves: the simulated supervisor takes over in every episode.
        "intervene-operator": ["collect", "--source", "intervene", "--policy", p, "--device", "operator", "--skill",
                               "expert", "--operator-id", "e1", "--task", TASK, "--num-episodes", str(episodes),
                               "--keep-failures", "--out", str(out)],
        "append": ["collect", "--source", "script", "--task", TASK, "--num-episodes", str(episodes), "--out", str(out),
                   "--append"],
        "merge": ["merge", s, h, "--out", str(out)],
        "filter": ["filter", s, "--where", "success", "--out", str(out)],
        "split": ["split", s, "--out", str(out), "--valid-fraction", "0.3"],
        "export": ["export", s, "--format", "robomimic", "--out", str(out)],
    }[path]


def _child(args: list[str], report_fd: int, log: Path) -> None:
    """In the forked child: run the command, writing one line per finished episode to the pipe."""
    code = 0
    try:
        fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        import typer

        from surrol_data.cli import app
        from surrol_data.datasets.recorder import DatasetRecorder

        original = DatasetRecorder.record

        def record_and_report(self, traj, provenance):
            index = original(self, traj, provenance)
            os.write(report_fd, f"{self.root}\n".encode())
            return index

        DatasetRecorder.record = record_and_report
        try:
            # Without standalone mode click *returns* the status of a command that ended by typer.Exit or Ctrl-C
            # (130): an interrupted export is no success, whose output would count as "finished".
            returned = typer.main.get_command(app).main(args=args, prog_name="surrol-data", standalone_mode=False)
            code = returned if isinstance(returned, int) else 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else 1
        except KeyboardInterrupt:
            code = 130
    except BaseException:  # noqa: BLE001 - reported through the exit status and the log
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _run(args: list[str], log: Path, delay: float | None, sig: int | None) -> tuple[dict, int, float]:
    """Fork, run ``args``, send ``sig`` after ``delay`` s (None: let it finish); (finished per root, exit, wall)."""
    read_fd, write_fd = os.pipe()
    t0 = time.monotonic()
    # SIGINT/SIGTERM stay blocked across the fork until the child is inside its own try/finally, so an early
    # signal can never let the child fall back into this function as a second parent.
    held = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, held)
    pid = os.fork()
    if pid == 0:
        try:
            os.close(read_fd)
            signal.pthread_sigmask(signal.SIG_UNBLOCK, held)
            _child(args, write_fd, log)
        finally:
            os._exit(1)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, held)
    os.close(write_fd)
    done, status = 0, 0
    if delay is not None:
        deadline = t0 + delay
        while time.monotonic() < deadline:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.005)
        else:
            os.kill(pid, sig)
    if not done:
        _, status = os.waitpid(pid, 0)
    wall = time.monotonic() - t0
    with os.fdopen(read_fd) as f:
        lines = [line.strip() for line in f.read().splitlines() if line.strip()]
    finished: dict = {}
    for line in lines:
        finished[line] = finished.get(line, 0) + 1
    return finished, os.waitstatus_to_exitcode(status), wall


def _still_policy(path: Path) -> Path:
    """A BC checkpoint of TASK whose action is always zero (the intervention path's policy)."""
    import torch

    from surrol_data.algos.bc import BCConfig, BCPolicy
    from surrol_data.algos.networks import DeterministicActor
    from surrol_data.algos.normalizer import Normalizer

    actor = DeterministicActor(7, 3, 5, (8,))
    with torch.no_grad():
        for weight in actor.parameters():
            weight.zero_()
    return BCPolicy(actor, Normalizer(7), Normalizer(3), BCConfig(hidden_sizes=(8,))).save(path)


def _build_bases(work: Path, which: tuple[str, ...] = ("script", "haptic", "policy")) -> dict:
    bases = {"script": work / "base_script", "haptic": work / "base_haptic"}
    if "policy" in which:
        bases["policy"] = _still_policy(work / "still_policy.pt")
    for name, args in (
            ("script", ["collect", "--source", "script", "--task", TASK, "--num-episodes", "6", "--out",
                        str(bases["script"])]),
            ("haptic", ["collect", "--source", "haptic", "--device", "operator", "--skill", "expert", "--operator-id",
                        "e1", "--task", TASK, "--num-episodes", "4", "--out", str(bases["haptic"])])):
        if name not in which:
            continue
        _, code, _ = _run(args, work / "base.log", None, None)
        if code != 0:
            raise SystemExit(f"building a base dataset failed: see {work / 'base.log'}")
    return bases


def _outputs(trial: Trial) -> list[Path]:
    if trial.path == "split":
        return [trial.out / "train", trial.out / "valid"]
    return [trial.out]


def _check_dataset(root: Path, expected: int, haptic: bool) -> dict:
    """Open ``root`` as our commands do; what was lost, whether it opens, repaired, traces, valid."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from surrol_data.datasets.writer import _holds_no_episode
    from surrol_data.datasets.guard import ensure_finished
    from surrol_data.datasets.reader import DatasetReader
    from surrol_data.datasets.validate import validate_dataset

    result = {"lost": 0, "opens": False, "repaired": False, "traces": None, "valid": False, "episodes": 0}
    if not root.exists() or _holds_no_episode(root):
        result.update(lost=expected, opens=True, valid=True)  # nothing there, and nothing blocks a retry
        return result
    notes: list[str] = []
    try:
        ensure_finished(root, notes.append)
        result["repaired"] = bool(notes)
        reader = DatasetReader(root)
        ds = LeRobotDataset(f"local/{root.name}", root=root, video_backend="pyav")
        if len(ds):
            ds[0]
            ds[len(ds) - 1]
        result["episodes"] = len(reader)
        result["opens"] = ds.num_episodes == len(reader)
        result["lost"] = max(0, expected - len(reader))
        if haptic:
            traces = [root / "meta" / "device_traces" / f"episode_{ep:06d}.npz" for ep in range(len(reader))]
            result["traces"] = all(t.exists() for t in traces)
        problems = validate_dataset(root, check_reward=False, check_lerobot=False)
        result["valid"] = problems == []
        if problems:
            result["problems"] = [str(p) for p in problems]
    except Exception as e:  # noqa: BLE001 - a dataset that cannot be opened is the finding
        result["error"] = f"{type(e).__name__}: {e}"
    return result


def _check_export(trial: Trial, total: int) -> dict:
    import h5py

    out = trial.out
    result = {"lost": 0, "opens": True, "repaired": False, "traces": None, "valid": True, "episodes": 0}
    if trial.exit_code == 0:
        trial.finished = {str(out): total}
    if out.exists():
        try:
            with h5py.File(out, "r") as f:
                result["episodes"] = len(f["data"])
        except Exception:  # noqa: BLE001
            result.update(opens=False, valid=False)
    result["lost"] = max(0, trial.finished.get(str(out), 0) - result["episodes"])
    return result


def kill_campaign(work: Path, paths: list[str], trials: int, signal_trials: int, seed: int, console: Console):
    rng = random.Random(seed)
    bases = _build_bases(work)
    episodes = {"script": 6, "haptic-operator": 3, "haptic-replay": 4, "intervene-operator": 3, "append": 4}
    runs: list[Trial] = []
    durations = {}
    for path in paths:
        out = work / f"{path}_calibrate" / ("out.hdf5" if path == "export" else "out")
        out.parent.mkdir(parents=True)
        if path == "append":
            shutil.copytree(bases["script"], out)
        _, code, wall = _run(_command(path, out, bases, episodes.get(path, 0)), out.parent / "log", None, None)
        if code != 0:
            raise SystemExit(f"{path}: an uninterrupted run failed (exit {code}); see {out.parent / 'log'}")
        durations[path] = wall
        kinds = ["KILL"] * trials + [("TERM", "INT")[i % 2] for i in range(signal_trials)]
        for i, kind in enumerate(kinds):
            out = work / f"{path}_{i:02d}" / ("out.hdf5" if path == "export" else "out")
            out.parent.mkdir(parents=True)
            trial = Trial(path, kind, out, delay=rng.uniform(0.0, 1.1 * wall))
            if path == "append":
                shutil.copytree(bases["script"], out)
                trial.base_episodes = 6
            trial.finished, trial.exit_code, _ = _run(_command(path, out, bases, episodes.get(path, 0)),
                                                      out.parent / "log", trial.delay, getattr(signal, f"SIG{kind}"))
            runs.append(trial)
        console.print(f"  {path}: {len(kinds)} trials (uninterrupted run {wall:.1f} s)")
    return runs, durations, bases


def summarize_kills(runs: list[Trial], bases: dict) -> Table:
    from surrol_data.datasets.reader import DatasetReader

    script_total = len(DatasetReader(bases["script"]))
    table = Table(title="Writer paths killed at random moments (SIGKILL, then SIGTERM/SIGINT)")
    for col in ("path", "signal", "trials", "finished episodes", "episodes lost", "max lost in a trial",
                "datasets open", "auto-repaired", "traces present", "valid after"):
        table.add_column(col, justify="right" if col not in ("path", "signal") else "left")
    groups: dict[tuple[str, str], list[dict]] = {}
    for trial in runs:
        checks = []
        if trial.path == "export":
            checks.append(_check_export(trial, script_total))
            finished = sum(trial.finished.values())
        else:
            finished = 0
            for root in _outputs(trial):
                n = trial.finished.get(str(root), 0)
                finished += n
                checks.append(_check_dataset(root, n + trial.base_episodes, trial.path in HAPTIC))
        merged = {"finished": finished, "lost": sum(c["lost"] for c in checks),
                  "opens": all(c["opens"] for c in checks), "repaired": any(c["repaired"] for c in checks),
                  "traces": None if trial.path not in HAPTIC else all(c["traces"] is not False for c in checks),
                  "valid": all(c["valid"] for c in checks), "errors": [c["error"] for c in checks if "error" in c]}
        merged["problems"] = [p for c in checks for p in c.get("problems", [])]
        if merged["errors"] or merged["lost"] or merged["problems"]:
            print(f"  {trial.path} {trial.sig} {trial.out}: {merged}", file=sys.stderr)
        groups.setdefault((trial.path, "SIGKILL" if trial.sig == "KILL" else "SIGTERM/SIGINT"), []).append(merged)
    totals = {"lost": 0, "trials": 0, "open": 0, "traces_missing": 0}
    for (path, sig), rows in groups.items():
        traces = [r["traces"] for r in rows if r["traces"] is not None]
        table.add_row(path, sig, str(len(rows)), str(sum(r["finished"] for r in rows)),
                      str(sum(r["lost"] for r in rows)), str(max(r["lost"] for r in rows)),
                      f"{sum(r['opens'] for r in rows)}/{len(rows)}", str(sum(r["repaired"] for r in rows)),
                      f"{sum(traces)}/{len(traces)}" if traces else "n/a",
                      f"{sum(r['valid'] for r in rows)}/{len(rows)}")
        totals["lost"] += sum(r["lost"] for r in rows)
        totals["trials"] += len(rows)
        totals["open"] += sum(r["opens"] for r in rows)
        totals["traces_missing"] += len(traces) - sum(traces)
    return table, totals


def fuzz_campaign(work: Path, console: Console) -> tuple[Table, dict]:
    from surrol_data.collect.corruptions import CLASSES, base_dataset, damaged_copy
    from surrol_data.datasets.guard import require_valid
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.datasets.validate import validate_dataset

    base = base_dataset(work / "fuzz_base")
    clean = validate_dataset(base, check_reward=False)
    if clean:
        raise SystemExit(f"the fuzz base dataset is not clean: {clean}")
    counts = {"detected": 0, "crashed": 0, "silent": 0, "refused": 0}
    timings = []
    for i, name in enumerate(CLASSES):
        root = damaged_copy(base, name, work / f"fuzz_{i:03d}")
        t0 = time.perf_counter()
        try:
            problems = validate_dataset(root, check_reward=False)  # LeRobotDataset check included
            counts["detected" if problems else "silent"] += 1
            if not problems:
                console.print(f"  silently passed: {name}")
        except Exception as e:  # noqa: BLE001
            counts["crashed"] += 1
            console.print(f"  crashed on {name}: {type(e).__name__}: {e}")
        timings.append(time.perf_counter() - t0)
        guard_root = damaged_copy(base, name, work / f"fuzz_guard_{i:03d}")
        notes: list[str] = []
        try:
            require_valid(guard_root, notes.append)
            refused = bool(notes)  # repaired automatically (an unfinished recording), with a message
        except DatasetError:
            refused = True
        except Exception:  # noqa: BLE001
            refused = False
        counts["refused"] += refused
        if not refused:
            console.print(f"  commands would accept: {name}")
    table = Table(title=f"Validation fuzz: {len(CLASSES)} damage classes (surrol_data.collect.corruptions)")
    for col in ("classes", "detected", "crashed", "silently passed", "refused/repaired by commands",
                "median validate time"):
        table.add_column(col, justify="right")
    table.add_row(str(len(CLASSES)), str(counts["detected"]), str(counts["crashed"]), str(counts["silent"]),
                  str(counts["refused"]), f"{statistics.median(timings):.2f} s")
    return table, {"classes": len(CLASSES), **counts}


# ---------------------------------------------------------------- part 3: every write site failed on purpose

FAULT_PATHS = ("script", "workers", "shards", "haptic-operator", "intervene-operator", "camera", "append", "merge",
               "filter", "split", "export", "upgrade", "adopt", "repair")
FAULT_ERRORS = ("ENOSPC", "EIO", "EROFS")
# the dataset each path writes, relative to the trial folder, and whether it is also the input (then the episodes it
# held before the run must all still be there)
_IN_PLACE = ("append", "upgrade", "adopt", "repair")
# paths whose output is not a recording (no journal, no repair): a failed run is taken up by running it again, as its
# error says; the trial checks that this succeeds and loses nothing
_RUN_AGAIN = ("adopt",)
# the base each in-place path works on (a copy of it)
_IN_PLACE_BASE = {"append": "script", "upgrade": "schema1", "adopt": "aggregated", "repair": "killed"}


def fault_bases(work: Path, paths=FAULT_PATHS) -> dict:
    """The inputs of the fault ``paths``, built once (real recordings; the repair's is a killed recording: a finished
    dataset whose journal holds two later episodes and whose last session never ended; the adoption's the script
    base rewritten by lerobot's aggregate_datasets)."""
    import json

    from surrol_data.datasets import journal
    from surrol_data.datasets.reader import DatasetReader

    which = (("script",) if set(paths) - {"upgrade"} else ()) + (("haptic",) if {"merge", "repair"} & set(paths) else
                                                                 ()) + (("policy",) if "intervene-operator" in paths
                                                                        else ())
    bases = _build_bases(work, which)
    bases["schema1"] = Path(__file__).resolve().parents[1] / "tests" / "data" / "schema1" / "needle_pick"
    if "adopt" in paths:
        bases["aggregated"] = _aggregated(bases["script"], work / "base_aggregated")
    if "repair" not in paths:
        return bases
    killed = work / "base_killed"
    shutil.copytree(bases["script"], killed)
    donor = DatasetReader(bases["haptic"])
    for i in range(2):
        provenance = {k: (v.item() if hasattr(v, "item") else v) for k, v in donor.episodes.iloc[i].items()
                      if k in ("source", "device", "skill", "seed", "operator_id", "task", "env_id")}
        journal.write_entry(killed, 6 + i, donor.trajectory(i), provenance)
    side_path = killed / "meta" / "surrol_data.json"
    side = json.loads(side_path.read_text())
    side["sessions"][-1].pop("ended_at", None)
    side_path.write_text(json.dumps(side))
    bases["killed"] = killed
    return bases


def _aggregated(source: Path, out: Path) -> Path:
    """``source`` rewritten by lerobot's own ``aggregate_datasets`` (what ``adopt`` takes back), made in a forked
    child so that lerobot's helper threads never start in this process, which forks every trial."""
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            from lerobot.datasets.aggregate import aggregate_datasets

            from surrol_data.datasets.hub_offline import hub_offline, local_repo_id

            with hub_offline():
                aggregate_datasets([local_repo_id(source)], local_repo_id(out), roots=[source], aggr_root=out)
            code = 0
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"aggregating {source} with lerobot's aggregate_datasets failed")
    return out


def fault_command(path: str, trial: Path, bases: dict) -> tuple[list[str], list[Path]]:
    """(the command's arguments, the datasets it writes) of one fault trial in the folder ``trial``."""
    s, h, p = str(bases["script"]), str(bases["haptic"]), str(bases.get("policy"))
    out = trial / "out"
    reach = ["--task", TASK, "--max-steps", "15", "--keep-failures"]
    if path in _IN_PLACE:
        shutil.copytree(bases[_IN_PLACE_BASE[path]], out)
    args = {
        # 11 episodes: a checkpoint after the 10th, so the session ends by consolidating two files into one
        "script": ["collect", "--source", "script", *reach, "--num-episodes", "11", "--out", str(out)],
        "workers": ["collect", "--source", "script", *reach, "--num-episodes", "3", "--workers", "2", "--out",
                    str(out)],
        "shards": ["collect", "--source", "script", *reach, "--num-episodes", "4", "--shards", "2", "--out", str(out)],
        "haptic-operator": ["collect", "--source", "haptic", "--device", "operator", "--skill", "expert",
                            "--operator-id", "e1", "--task", TASK, "--num-episodes", "2", "--out", str(out)],
        "intervene-operator": ["collect", "--source", "intervene", "--policy", p, "--device", "operator", "--skill",
                               "expert", "--operator-id", "e1", "--task", TASK, "--num-episodes", "2",
                               "--keep-failures", "--out", str(out)],
        "camera": ["collect", "--source", "script", *reach, "--num-episodes", "2", "--camera", "--camera-size",
                   "32x32", "--out", str(out)],
        "append": ["collect", "--source", "script", *reach, "--num-episodes", "2", "--append", "--out", str(out)],
        "merge": ["merge", s, h, "--out", str(out)],
        "filter": ["filter", s, "--where", "seed >= 0", "--out", str(out)],
        "split": ["split", s, "--out", str(out), "--valid-fraction", "0.3"],
        "export": ["export", s, "--format", "robomimic", "--out", str(trial / "out.hdf5")],
        "upgrade": ["upgrade", str(out)],
        "adopt": ["adopt", str(out), "--from", s],
        "repair": ["repair", str(out)],
    }[path]
    outputs = {"split": [out / "train", out / "valid"], "export": [trial / "out.hdf5"]}.get(path, [out])
    return args, outputs


def fault_run(args: list[str], log: Path, fail_at: int | None, error: str) -> dict:
    """Fork; in the child run ``args`` under a :class:`FaultInjector` (``fail_at`` None: count the sites), reporting
    the exit status, the sites called, the call failed and every finished episode (root, content hash)."""
    import json

    read_fd, write_fd = os.pipe()
    real_write = os.write
    pid = os.fork()
    if pid == 0:
        report: dict = {"code": None}
        try:
            os.close(read_fd)
            fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            import typer

            from surrol_data.cli import app
            from surrol_data.datasets.fault_injection import FaultInjector
            from surrol_data.datasets.schema import content_hash
            from surrol_data.datasets.writer import DatasetWriter

            finished: list = []
            original = DatasetWriter.record

            def record(self, traj, provenance):
                index = original(self, traj, provenance)
                finished.append([str(self.root), content_hash(self._frame_arrays(traj), self.features)])
                return index

            DatasetWriter.record = record
            injector = FaultInjector(fail_at, error)
            with injector:
                try:
                    returned = typer.main.get_command(app).main(args=args, prog_name="surrol-data",
                                                                standalone_mode=False)
                    code = returned if isinstance(returned, int) else 0
                except SystemExit as e:
                    code = e.code if isinstance(e.code, int) else 1
                except BaseException:  # noqa: BLE001 - an escaped exception is the finding
                    import traceback

                    traceback.print_exc()
                    code = "traceback"
            report = {"code": code, "sites": injector.sites, "failed": injector.failed, "finished": finished}
        except BaseException as e:  # noqa: BLE001
            report = {"code": f"harness: {type(e).__name__}: {e}"}
        finally:
            data = json.dumps(report).encode()
            while data:
                data = data[real_write(write_fd, data):]
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as f:
        raw = f.read()
    os.waitpid(pid, 0)
    return json.loads(raw) if raw else {"code": "child died"}


def _hashes(root: Path) -> list[str]:
    from surrol_data.datasets.reader import DatasetReader

    return [str(h) for h in DatasetReader(root).episodes["content_hash"]]


def fault_check(path: str, result: dict, outputs: list[Path], expected: dict, before: list[str], log: Path) -> dict:
    """What one fault trial left: episodes lost / duplicated, tracebacks, whether the error was one line naming what is
    kept, whether every output opens (after the automatic repair)."""
    import h5py

    from surrol_data.datasets.guard import ensure_finished
    from surrol_data.datasets.writer import _holds_no_episode

    said = log.read_text(errors="replace")
    code = result.get("code")
    row = {"lost": 0, "duplicated": 0, "traceback": code == "traceback" or "Traceback" in said or not isinstance(
        code, int), "message_ok": True, "opens": True, "problem": ""}
    if code not in (0, None) and isinstance(code, int):
        flat = " ".join(said.split())
        row["message_ok"] = (code == 2 and flat.count("error:") == 1
                             and any(w in flat for w in ("kept", "unchanged", "nothing was written", "is whole", "left as it was")))
    finished: dict[str, list[str]] = {}
    for root, digest in result.get("finished", []):
        finished.setdefault(root, []).append(digest)
    for out in outputs:
        must = set(finished.get(str(out), []))
        if code == 0:
            must |= set(expected.get(str(out), []))
        if path in _IN_PLACE and path != "upgrade":
            must |= set(before)
        if out.suffix == ".hdf5":
            if out.exists():
                try:
                    with h5py.File(out, "r") as f:
                        row["opens"] &= len(f["data"]) == len(expected.get(str(out), [])) or code != 0
                except Exception as e:  # noqa: BLE001
                    row.update(opens=False, problem=f"{out.name}: {type(e).__name__}: {e}")
            elif code == 0:
                row.update(opens=False, problem="export said done but wrote no file")
            continue
        if not out.exists() or _holds_no_episode(out):
            row["lost"] += len(must)
            continue
        try:
            ensure_finished(out, lambda message: None)
            present = _hashes(out)
        except Exception as e:  # noqa: BLE001 - an output that cannot be opened is the finding
            row.update(opens=False, problem=f"{out.name}: {type(e).__name__}: {str(e)[:200]}")
            continue
        row["lost"] += len(must - set(present))
        row["duplicated"] += sum(present.count(h) - 1 for h in set(present) if present.count(h) > 1)
    if "again" in result and result["again"] != 0:
        row.update(opens=False, problem=f"running the command again failed ({result['again']})")
    if path == "upgrade" and code != 0:   # the original must be as it was: all its episodes, schema 1
        row["lost"] += 0 if outputs[0].exists() else 1
    return row


def fault_campaign(work: Path, paths: list[str], errors: list[str], console: Console, limit: int | None = None,
                   occurrences: str = "first") -> tuple[Table, dict]:
    """Every write site of every path × every error: count the sites in a clean run, then fail each in a run of its
    own (its first call; ``occurrences="all"``: every call). ``limit``: at most that many sites per path."""
    from surrol_data.datasets.fault_injection import distinct_sites

    bases = fault_bases(work, paths)
    table = Table(title="Every write site failed on purpose (ENOSPC sticky for writes, EROFS sticky, EIO once)")
    for col in ("path", "sites", "calls", "trials", "finished episodes", "lost", "duplicated", "tracebacks",
                "one-line error", "opens"):
        table.add_column(col, justify="left" if col == "path" else "right")
    totals = {"sites": 0, "trials": 0, "lost": 0, "duplicated": 0, "tracebacks": 0, "bad_messages": 0,
              "not_open": 0, "finished": 0}
    for path in paths:
        started, cpu = time.monotonic(), _cpu_s()
        clean = work / f"faults_{path}_clean"
        clean.mkdir()
        args, outputs = fault_command(path, clean, bases)
        before = _hashes(outputs[0]) if path in _IN_PLACE and path != "upgrade" else []
        counted = fault_run(args, clean / "log", None, "ENOSPC")
        if counted.get("code") != 0:
            raise SystemExit(f"{path}: the run without faults failed ({counted.get('code')}); see {clean / 'log'}")
        expected = {str(o): (_hashes(o) if o.suffix != ".hdf5" else list(range(6))) for o in outputs}
        sites = distinct_sites(counted["sites"])
        calls = list(sites.values()) if occurrences == "first" else list(range(len(counted["sites"])))
        if limit and len(calls) > limit:   # spread over the run: the first, the last and evenly between
            calls = [calls[round(i * (len(calls) - 1) / (limit - 1))] for i in range(limit)] if limit > 1 else calls[:1]
        rows = []
        for error in errors:
            for k in calls:
                trial = work / f"faults_{path}_{error}_{k:05d}"
                trial.mkdir()
                args, outputs = fault_command(path, trial, bases)
                result = fault_run(args, trial / "log", k, error)
                if path in _RUN_AGAIN and result.get("code") not in (0, None) and isinstance(result.get("code"), int):
                    # what its error says to do: run the command again (once there is space)
                    again = fault_run(args, trial / "again.log", None, error)
                    result["again"] = again.get("code")
                row = fault_check(path, result, [Path(str(o).replace(str(clean), str(trial))) for o in outputs],
                                  {str(o).replace(str(clean), str(trial)): v for o, v in expected.items()},
                                  before, trial / "log")
                row["finished"] = len(result.get("finished", []))
                rows.append(row)
                bad = row["lost"] or row["duplicated"] or row["traceback"] or not row["message_ok"] or not row["opens"]
                if bad:
                    console.print(f"  {path} {error} call {k} ({result.get('failed')}): {row} log {trial / 'log'}")
                else:
                    shutil.rmtree(trial, ignore_errors=True)
        agg = {key: sum(r[key] for r in rows) for key in ("lost", "duplicated", "finished")}
        tracebacks = sum(r["traceback"] for r in rows)
        messages = sum(r["message_ok"] for r in rows)
        opens = sum(r["opens"] for r in rows)
        table.add_row(path, str(len(sites)), str(len(counted["sites"])), str(len(rows)), str(agg["finished"]),
                      str(agg["lost"]), str(agg["duplicated"]), str(tracebacks), f"{messages}/{len(rows)}",
                      f"{opens}/{len(rows)}")
        # each path's row as soon as it is done: an exhaustive sweep takes hours, and its table comes at the end
        console.print(f"  {path}: {len(sites)} sites, {len(counted['sites'])} calls, {len(rows)} trials, "
                      f"{agg['finished']} finished episodes, {agg['lost']} lost, {agg['duplicated']} duplicated, "
                      f"{tracebacks} tracebacks, {messages}/{len(rows)} one-line errors, {opens}/{len(rows)} open; "
                      f"{time.monotonic() - started:.0f} s, {_cpu_s() - cpu:.0f} s CPU")
        totals["sites"] += len(sites)
        totals["trials"] += len(rows)
        totals["lost"] += agg["lost"]
        totals["duplicated"] += agg["duplicated"]
        totals["finished"] += agg["finished"]
        totals["tracebacks"] += tracebacks
        totals["bad_messages"] += len(rows) - messages
        totals["not_open"] += len(rows) - opens
    return table, totals


# ---------------------------------------------------------------- part 4: a real small tmpfs filled during each path

_PAGE = 4096
_ROOMY = "256m"


def _mount_tmpfs(where: Path, size: str) -> None:
    import subprocess

    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        raise SystemExit(f"cannot mount a tmpfs at {where} ({done.stderr.strip()}): run as root")


def _remount(where: Path, size: str) -> None:
    import subprocess

    subprocess.run(["mount", "-o", f"remount,size={size}", str(where)], check=True, capture_output=True)


def _used(where: Path) -> int:
    st = os.statvfs(where)
    return (st.f_blocks - st.f_bfree) * st.f_frsize


@contextlib.contextmanager
def _peak_use(where: Path):
    """``[bytes]``: the most ``where``'s file system held while the block ran (sampled every 2 ms by a thread of
    this process; the forked child it waits for is not slowed)."""
    import threading

    peak, done = [_used(where)], threading.Event()

    def sample() -> None:
        while not done.wait(0.002):
            peak[0] = max(peak[0], _used(where))

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    try:
        yield peak
    finally:
        done.set()
        thread.join()


def tmpfs_campaign(work: Path, paths: list[str], fill: float, console: Console) -> tuple[Table, dict]:
    """Each path run on a real tmpfs too small for it: a clean run on a roomy tmpfs measures the most the path has
    written at once (its input copied in first for a path that works in place), then a tmpfs of the input's size plus ``fill`` of
    that is mounted, the input copied in, and the path run until the disk is full; the tmpfs is then enlarged
    (``mount -o remount``) and the trial checked as a fault trial is (nothing finished lost or duplicated, the error
    one line naming what is kept, no traceback, the output opens after the automatic repair). Needs its own mount
    namespace (``main`` re-runs the script under ``unshare --mount``)."""
    bases = fault_bases(work, paths)
    table = Table(title=f"A real tmpfs filled during each path (room for {fill:.0%} of the most it writes at once)")
    for col in ("path", "writes", "tmpfs", "filled", "finished episodes", "lost", "duplicated", "tracebacks",
                "one-line error", "opens"):
        table.add_column(col, justify="left" if col == "path" else "right")
    totals = {"paths": 0, "filled": 0, "lost": 0, "duplicated": 0, "tracebacks": 0, "bad_messages": 0,
              "not_open": 0, "finished": 0}
    mounted: list[Path] = []
    try:
        for path in paths:
            clean, trial = work / f"tmpfs_{path}_clean" / "disk", work / f"tmpfs_{path}" / "disk"
            clean.mkdir(parents=True)
            _mount_tmpfs(clean, _ROOMY)
            mounted.append(clean)
            args, outputs = fault_command(path, clean, bases)
            before = _hashes(outputs[0]) if path in _IN_PLACE and path != "upgrade" else []
            input_bytes = _used(clean)
            with _peak_use(clean) as peak:
                counted = fault_run(args, clean.parent / "log", None, "ENOSPC")
            if counted.get("code") != 0:
                raise SystemExit(f"{path}: the run on a roomy tmpfs failed ({counted.get('code')}); see "
                                 f"{clean.parent / 'log'}")
            written = max(peak[0], _used(clean)) - input_bytes   # the most it had on the disk at once
            expected = {str(o): (_hashes(o) if o.suffix != ".hdf5" else list(range(6))) for o in outputs}
            size = input_bytes + max(_PAGE, int(written * fill) // _PAGE * _PAGE)
            trial.mkdir(parents=True)
            _mount_tmpfs(trial, str(size))
            mounted.append(trial)
            args, outputs = fault_command(path, trial, bases)
            result = fault_run(args, trial.parent / "log", None, "ENOSPC")
            _remount(trial, _ROOMY)   # the disk enlarged: what the error said to do can now be done
            filled = result.get("code") != 0
            if path in _RUN_AGAIN and filled and isinstance(result.get("code"), int):
                result["again"] = fault_run(args, trial.parent / "again.log", None, "ENOSPC").get("code")
            row = fault_check(path, result, [Path(str(o).replace(str(clean), str(trial))) for o in outputs],
                              {str(o).replace(str(clean), str(trial)): v for o, v in expected.items()}, before,
                              trial.parent / "log")
            said = " ".join((trial.parent / "log").read_text(errors="replace").split())
            if filled and "no space left on the disk" not in said:
                row.update(message_ok=False, problem=row["problem"] or "the error does not say the disk is full")
            finished = len(result.get("finished", []))
            bad = row["lost"] or row["duplicated"] or row["traceback"] or not row["message_ok"] or not row["opens"]
            if bad or not filled:
                console.print(f"  {path}: {'filled' if filled else 'NOT filled (it fit)'} {row} log "
                              f"{trial.parent / 'log'}")
            table.add_row(path, f"{written / 1e3:.0f} kB", f"{size / 1e3:.0f} kB", "yes" if filled else "no",
                          str(finished), str(row["lost"]), str(row["duplicated"]), str(int(row["traceback"])),
                          "yes" if row["message_ok"] else "no", "yes" if row["opens"] else "no")
            for key in ("lost", "duplicated"):
                totals[key] += row[key]
            totals["paths"] += 1
            totals["filled"] += filled
            totals["finished"] += finished
            totals["tracebacks"] += row["traceback"]
            totals["bad_messages"] += not row["message_ok"]
            totals["not_open"] += not row["opens"]
    finally:
        import subprocess

        for where in reversed(mounted):
            subprocess.run(["umount", "-l", str(where)], capture_output=True)
    return table, totals


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished children (each trial is a forked child)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _in_private_mounts(argv: list[str]) -> None:
    """Run this script again in a mount namespace of its own (``unshare --mount``: root), so its tmpfs mounts are
    nobody else's and vanish with it whatever happens; exits with its status."""
    import shutil as which
    import subprocess

    if which.which("unshare") is None:
        raise SystemExit("--tmpfs needs unshare (util-linux) and root")
    done = subprocess.run(["unshare", "--mount", "--propagation", "private", sys.executable, *argv,
                           "--in-private-mounts"])
    raise SystemExit(done.returncode)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20, help="SIGKILL trials per writer path")
    parser.add_argument("--signal-trials", type=int, default=6, help="SIGTERM/SIGINT trials per writer path")
    parser.add_argument("--paths", nargs="+", default=list(PATHS), choices=PATHS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-fuzz", action="store_true")
    parser.add_argument("--no-kills", action="store_true")
    parser.add_argument("--keep", action="store_true", help="keep the work folder (printed)")
    parser.add_argument("--faults", action="store_true", help="only part 3: fail every write site of every path")
    parser.add_argument("--fault-paths", nargs="+", default=list(FAULT_PATHS), choices=FAULT_PATHS)
    parser.add_argument("--fault-errors", nargs="+", default=list(FAULT_ERRORS), choices=FAULT_ERRORS)
    parser.add_argument("--fault-sites", type=int, default=None, help="at most this many sites per path, spread over the run (a quick look)")
    parser.add_argument("--tmpfs", action="store_true", help="only part 4: fill a real small tmpfs during each path "
                                                                 "(root: its own mount namespace)")
    parser.add_argument("--tmpfs-paths", nargs="+", default=list(FAULT_PATHS), choices=FAULT_PATHS)
    parser.add_argument("--tmpfs-fill", type=float, default=0.5,
                        help="room on the tmpfs, as a fraction of what the path writes")
    parser.add_argument("--in-private-mounts", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    console = Console(width=150)
    if args.tmpfs and not args.in_private_mounts:
        _in_private_mounts(sys.argv)

    # Heavy imports once, before any fork: each trial then costs only its own work.
    import lerobot.datasets.lerobot_dataset  # noqa: F401

    import surrol_data.cli  # noqa: F401
    import surrol_data.collect.haptic_source  # noqa: F401
    import surrol_data.collect.script_source  # noqa: F401
    import surrol_data.envs  # noqa: F401

    work = Path(tempfile.mkdtemp(prefix="crash_safety_"))
    ok = True
    try:
        if args.tmpfs:
            import h5py  # noqa: F401  (imported before the fork, as for the fault campaign)

            console.print(f"tmpfs campaign in {work} ...")
            t0, c0 = time.monotonic(), _cpu_s()
            table, totals = tmpfs_campaign(work, args.tmpfs_paths, args.tmpfs_fill, console)
            console.print(table)
            console.print(f"{totals['paths']} paths on a real tmpfs, {totals['filled']} filled it, in "
                          f"{time.monotonic() - t0:.0f} s ({_cpu_s() - c0:.0f} s CPU): {totals['finished']} finished episodes, {totals['lost']} "
                          f"lost, {totals['duplicated']} duplicated, {totals['tracebacks']} tracebacks, "
                          f"{totals['bad_messages']} errors not one line naming what is kept, {totals['not_open']} "
                          "outputs that do not open")
            ok &= not (totals["lost"] or totals["duplicated"] or totals["tracebacks"] or totals["bad_messages"]
                       or totals["not_open"]) and totals["filled"] == totals["paths"]
            args.no_kills = args.no_fuzz = True
            args.faults = False
        if args.faults:
            import h5py  # noqa: F401  (imported before the fork, so that the injector wraps its File)

            console.print(f"fault campaign in {work} ...")
            t0, c0 = time.monotonic(), _cpu_s()
            table, totals = fault_campaign(work, args.fault_paths, args.fault_errors, console, args.fault_sites)
            console.print(table)
            console.print(f"{len(args.fault_paths)} paths, {totals['sites']} write sites, {totals['trials']} trials in "
                          f"{time.monotonic() - t0:.0f} s ({_cpu_s() - c0:.0f} s CPU, trials included): "
                          f"{totals['finished']} finished episodes, {totals['lost']} lost, {totals['duplicated']} "
                          f"duplicated, {totals['tracebacks']} tracebacks, {totals['bad_messages']} errors not one "
                          f"line naming what is kept, {totals['not_open']} outputs that do not open")
            ok &= not (totals["lost"] or totals["duplicated"] or totals["tracebacks"] or totals["bad_messages"]
                       or totals["not_open"])
            args.no_kills = args.no_fuzz = True
        if not args.no_kills:
            console.print(f"kill campaign in {work} ...")
            t0 = time.monotonic()
            runs, _, bases = kill_campaign(work, args.paths, args.trials, args.signal_trials, args.seed, console)
            table, totals = summarize_kills(runs, bases)
            console.print(table)
            console.print(f"{totals['trials']} trials in {time.monotonic() - t0:.0f} s: {totals['lost']} finished "
                          f"episodes lost, {totals['open']}/{totals['trials']} datasets open, "
                          f"{totals['traces_missing']} trace sets incomplete")
            ok &= totals["lost"] == 0 and totals["open"] == totals["trials"] and totals["traces_missing"] == 0
        if not args.no_fuzz:
            table, counts = fuzz_campaign(work, console)
            console.print(table)
            ok &= counts["crashed"] == 0 and counts["silent"] == 0 and counts["refused"] == counts["classes"]
    finally:
        if args.keep:
            console.print(f"work folder kept: {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    raise SystemExit(0 if ok else 1)


if __name__ == "__main__":
    main()

"""A study's demo sets: built once, shipped as data, hashed, and described by a demo-quality table.

The matched and natural sets of the Table I study are LeRobot v3 datasets committed under ``datasets/`` (the
config's ``demo_dir`` / ``natural_demo_dir``) with a manifest, ``demo_sets.json``, that records each set's content
hash. Runs read them from there and record the hash, so later changes to the operator models or the device mapping
cannot change the study. A study without shipped sets (``table1_quick``) builds its own under ``OUT/demos``.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

from surrol_data.evaluation.recovery_report import object_name
from surrol_data.evaluation.report import Column, metrics_table_markdown
from surrol_data.study.spec import SKILL_OF_SOURCE, StudySpec, operator_ids

MANIFEST = "demo_sets.json"
# The paper's demo sets (NeedlePick, 100 episodes each): mean completion steps and tool-tip path. A study of another
# task matches its sources to one another instead: each within MATCH_TOLERANCE of the sources' mean.
PAPER_TASK = "NeedlePick"
PAPER_DEMOS = {"expert": (113.0, 12.1), "novice": (117.0, 12.5), "script": (109.0, 11.7)}
MATCH_TOLERANCE = 0.10
_FIRST_COLUMNS = (Column("source", "Source"), Column("episodes", "Episodes"),
                  Column("steps_to_success", "Steps to complete", lambda v: f"{v:.1f}"))
_LATER_COLUMNS = (
    Column("matched", "Within ±10 %", str),
    Column("sparc", "SPARC", lambda v: f"{v:.2f}"),
    Column("log_dimensionless_jerk", "LDLJ", lambda v: f"{v:.1f}"),
    Column("idle_time_s", "Idle (s)", lambda v: f"{v:.1f}"),
    Column("failed_grasps", "Failed grasps", lambda v: f"{v:.2f}"),
    Column("failed_attempts", "Failed attempts", lambda v: f"{v:.2f}"),
    Column("retries", "Retries", lambda v: f"{v:.2f}"),
    Column("jaw_closures", "Jaw closures", lambda v: f"{v:.2f}"),
    Column("clutch_uses", "Clutch", lambda v: f"{v:.1f}"),
)


def demo_columns(task: str = PAPER_TASK) -> tuple[Column, ...]:
    """The demo table's columns: beside each source's steps and path, the paper's (NeedlePick) or the sources' mean
    (another task), which "Within ±10 %" compares them with."""
    against = "Paper" if task == PAPER_TASK else "Sources' mean"
    return (*_FIRST_COLUMNS, Column("paper_steps", f"{against} steps", lambda v: f"{v:.0f}"),
            Column("path_length_cm", "Path (cm)", lambda v: f"{v:.2f}"),
            Column("paper_path", f"{against} path (cm)", lambda v: f"{v:.1f}"), *_LATER_COLUMNS)


class DemoSetError(ValueError):
    """A shipped demo set that is missing or differs from its recorded hash: what and what to do."""


def tree_hash(root: Path) -> str:
    """sha256 over every file under ``root``: relative path and bytes, in path order."""
    h = hashlib.sha256()
    for path in sorted(p for p in Path(root).rglob("*") if p.is_file()):
        h.update(path.relative_to(root).as_posix().encode() + b"\0")
        h.update(hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()


def set_paths(root: Path, spec: StudySpec) -> dict[str, Path]:
    """source -> dataset folder: ``<Task>_script`` for the oracle, ``<Task>_human`` for both human skills."""
    return {s: Path(root) / f"{spec.task}_{'script' if s == 'script' else 'human'}" for s in spec.sources}


def _episode_counts(root: Path) -> dict[tuple[str, str], int]:
    """Episodes per (skill, operator_id) already in the dataset at ``root`` (empty when there is none)."""
    if not (root / "meta" / "info.json").exists():
        return {}
    from surrol_data.datasets.guard import ensure_finished
    from surrol_data.datasets.reader import DatasetReader

    ensure_finished(root)
    episodes = DatasetReader(root).episodes
    return episodes.groupby(["skill", "operator_id"]).size().to_dict() if len(episodes) else {}


def build_demo_sets(root: str | Path, spec: StudySpec, progress: bool = True) -> dict[str, Path]:
    """Record the study's demo sets under ``root`` (continuing any already begun); returns source -> dataset."""
    from surrol_data.collect.haptic_source import collect_haptic
    from surrol_data.collect.script_source import SCRIPT_SPEED_MATCHED, collect_script

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    sets = set_paths(root, spec)
    if "script" in spec.sources:
        have = sum(_episode_counts(sets["script"]).values())
        if have < spec.episodes:
            collect_script(spec.task, spec.episodes - have, sets["script"], seed=None, max_steps=spec.horizon,
                           append=True, progress=progress, speed=SCRIPT_SPEED_MATCHED if spec.matched else 1.0,
                           command=f"surrol-data study {spec.experiment}")
    per_operator = spec.episodes // spec.operators
    for skill in ("novice", "expert"):
        if skill not in spec.sources:
            continue
        human = sets[skill]
        for operator in operator_ids(skill, spec.operators):
            have = _episode_counts(human).get((skill, operator), 0)
            if have >= per_operator:
                continue
            # seed=None with append: each operator's episodes continue the dataset's seed sequence, so no two
            # episodes of the set share a scene and a resumed build never repeats one.
            collect_haptic(spec.task, per_operator - have, human, device="operator", operator_id=operator,
                           skill=skill, profile=f"{skill}_matched" if spec.matched else None, seed=None,
                           max_steps=spec.horizon, append=True, progress=progress, max_attempts=10 * per_operator,
                           command=f"surrol-data study {spec.experiment}")
    return sets


def build_shipped_demo_sets(root: Path, spec: StudySpec, progress: bool = True) -> dict[str, Path]:
    """Build the sets to ship under ``root``: recorded in ``root/.build`` (resumable), then each copied into its
    final folder by ``merge`` (lerobot's aggregate_datasets), which packs an append-built dataset's one metadata
    file per episode into one file (a 200-episode set: ~40 MB → ~9 MB); then the manifest."""
    import shutil

    from surrol_data.datasets.merge import merge_datasets

    if (root / MANIFEST).is_file():
        raise DemoSetError(f"{root / MANIFEST} exists: the study's demo sets are built. To rebuild them (which voids "
                           f"every run trained on them), delete {root} first")
    staging = root / ".build"
    built = build_demo_sets(staging, spec, progress=progress)
    finals = set_paths(root, spec)
    for source, path in built.items():
        final = finals[source]
        if not final.exists():
            merge_datasets(final, [path], command=f"surrol-data study {spec.experiment} --build-demos",
                           progress=progress)
    shutil.rmtree(staging)
    write_manifest(root, spec, finals)
    return finals


def write_manifest(root: Path, spec: StudySpec, sets: dict[str, Path]) -> dict:
    """Record every set's hash and episode count in ``root/demo_sets.json``; returns the manifest."""
    from surrol_data.datasets.reader import DatasetReader

    entries = {}
    for path in dict.fromkeys(sets.values()):
        entries[path.name] = {"sha256": tree_hash(path), "episodes": len(DatasetReader(path).episodes)}
    manifest = {"experiment": spec.experiment, "task": spec.task, "matched": spec.matched,
                "episodes_per_source": spec.episodes, "operators_per_skill": spec.operators,
                "horizon": spec.horizon, "sets": entries}
    (root / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def check_shipped(root: Path, spec: StudySpec) -> dict[str, str]:
    """The shipped sets' hashes (dataset name -> sha256) after checking each against the manifest."""
    manifest_path = root / MANIFEST
    if not manifest_path.is_file():
        raise DemoSetError(f"{manifest_path} is missing: the study's demo sets are not built. Build them once with "
                           f"`surrol-data study {spec.experiment} --build-demos` and commit {root}.")
    manifest = json.loads(manifest_path.read_text())
    if manifest.get("matched") != spec.matched or manifest.get("episodes_per_source") != spec.episodes:
        raise DemoSetError(f"{manifest_path} describes other demo sets (matched {manifest.get('matched')}, "
                           f"{manifest.get('episodes_per_source')} per source) than study {spec.experiment} asks for "
                           f"(matched {spec.matched}, {spec.episodes}); point demo_dir at the right folder")
    hashes = {}
    for path in dict.fromkeys(set_paths(root, spec).values()):
        recorded = manifest["sets"].get(path.name, {}).get("sha256")
        if recorded is None or not path.is_dir():
            raise DemoSetError(f"{path} is not among the shipped demo sets of {manifest_path}; restore it "
                               f"(`git checkout -- {root}`) or rebuild them with --build-demos")
        actual = tree_hash(path)
        if actual != recorded:
            raise DemoSetError(f"{path} differs from the hash recorded in {manifest_path} ({actual[:12]} ≠ "
                               f"{recorded[:12]}): the study's demos must not change while it runs. Restore them with "
                               f"`git checkout -- {path}`")
        hashes[path.name] = actual
    return hashes


def demo_quality(sets: dict[str, Path], task: str = PAPER_TASK) -> list[dict]:
    """One row per demo source: the assessment's per-skill means with what they are matched to beside them: the
    paper's demo figures on its task (NeedlePick), the sources' mean steps and path on another."""
    from surrol_data.evaluation.assess import assess_dataset

    rows = []
    assessed: dict[Path, object] = {}
    for source, path in sets.items():
        if path not in assessed:
            assessed[path] = assess_dataset(path)
        result = assessed[path]
        ep = result.episodes[result.episodes["skill"] == SKILL_OF_SOURCE[source]]
        ok = ep[ep["success"]]
        steps, path_cm = float(ok["steps_to_success"].mean()), float(ok["path_length_cm"].mean())

        def mean(frame, col):
            v = frame[col].astype(float)
            return float(v.mean()) if v.notna().any() else math.nan

        rows.append({"source": source, "episodes": len(ep), "steps_to_success": steps,
                     "failed_attempts": mean(ep, "failed_attempts") if "failed_attempts" in ep else math.nan,
                     "retries": mean(ep, "retries") if "retries" in ep else math.nan,
                     "per_demo": _per_demo(ep), "path_length_cm": path_cm,
                     "sparc": mean(ok, "sparc"), "log_dimensionless_jerk": mean(ok, "log_dimensionless_jerk"),
                     "idle_time_s": mean(ep, "idle_time_s"), "failed_grasps": mean(ep, "failed_grasps"),
                     "jaw_closures": mean(ep, "jaw_closures"), "clutch_uses": mean(ep, "clutch_uses")})
    sources_mean = (sum(r["steps_to_success"] for r in rows) / len(rows),
                    sum(r["path_length_cm"] for r in rows) / len(rows))
    for row in rows:
        row["paper_steps"], row["paper_path"] = PAPER_DEMOS[row["source"]] if task == PAPER_TASK else sources_mean
        within = (abs(row["steps_to_success"] / row["paper_steps"] - 1) <= MATCH_TOLERANCE
                  and abs(row["path_length_cm"] / row["paper_path"] - 1) <= MATCH_TOLERANCE)
        row["matched"] = "yes" if within else "no"
    return rows


# The per-demo distributions demos.md shows beside the means: (column, header, successes only, digits).
DISTRIBUTIONS = (("steps_to_success", "Steps to complete", True, 0), ("path_length_cm", "Path (cm)", True, 1),
                 ("failed_attempts", "Failed attempts", False, 0), ("retries", "Retries", False, 0))


def _per_demo(ep) -> dict[str, list[float]]:
    """Each distribution's values, one per demo (successful demos only for steps and path)."""
    out = {}
    for col, _, successes, _ in DISTRIBUTIONS:
        if col in ep:
            frame = ep[ep["success"]] if successes else ep
            out[col] = [float(v) for v in frame[col].astype(float) if math.isfinite(v)]
    return out


def _spread(values: list[float], digits: int) -> str:
    """median [quartiles], range"""
    import numpy as np

    if not values:
        return "—"
    q = np.percentile(values, [0, 25, 50, 75, 100])
    f = f"{{:.{digits}f}}"
    return f"{f.format(q[2])} [{f.format(q[1])}–{f.format(q[3])}], {f.format(q[0])}–{f.format(q[4])}"


def _counts(values: list[float]) -> str:
    """Share (%) of demos with 0, 1, 2 and 3 or more (of a count)."""
    if not values:
        return "—"
    n = len(values)
    shares = [sum(v == k for v in values) for k in (0, 1, 2)] + [sum(v >= 3 for v in values)]
    return " / ".join(f"{100 * c / n:.0f}" for c in shares)


def demo_distributions_markdown(rows: list[dict]) -> str:
    """Per source, the distribution over its demos of steps, path, failed attempts and retries."""
    lines = ["| Source | " + " | ".join(h for _, h, _, _ in DISTRIBUTIONS)
             + " | Failed attempts 0 / 1 / 2 / 3+ (% of demos) | Retries 0 / 1 / 2 / 3+ (% of demos) |",
             "|:---|" + "---:|" * (len(DISTRIBUTIONS) + 2)]
    for row in rows:
        per = row.get("per_demo", {})
        cells = [_spread(per.get(col, []), digits) for col, _, _, digits in DISTRIBUTIONS]
        cells += [_counts(per.get("failed_attempts", [])), _counts(per.get("retries", []))]
        lines.append(f"| {row['source']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def demo_quality_markdown(rows: list[dict], matched: bool, task: str = PAPER_TASK) -> str:
    kind = ("natural (each operator's own pace; not matched)" if not matched else "matched to the paper's demo sets"
            if task == PAPER_TASK else "matched to one another (each source's steps and path within ±10 % of the "
            "sources' mean)")
    return (f"Demo sets {kind}. Steps and path: means over successful episodes; smoothness (SPARC, LDLJ: higher is "
            "smoother) from the device trace where there is one (the simulated operators'), from the tool tip for "
            "the script; idle, failed grasps, failed attempts, retries, jaw closures and clutch uses: means per "
            "episode. "
            f"A failed attempt is a grasp attempt near the {object_name(task)} that never held it or lost it before "
            "a 5 mm lift, a retry an attempt after a failed one (datasets/attempts.py); successful demos may contain "
            "both. The human demos come from simulated operators (a motor-control model), not from people.\n\n"
            + metrics_table_markdown(rows, demo_columns(task))
            + "\nPer demo: median [quartiles], range (steps and path over successful demos; counts over all demos).\n\n"
            + demo_distributions_markdown(rows))

"""The demo-source study (the paper's Table I) as one command: demo sets, training, report.

    surrol-data study table1 --out docs/results/table1                   # matched demo sources (the paper's)
    surrol-data study table1 --natural --out docs/results/table1_natural # the operators' own pace

The experiment config (``configs/experiment/<name>.yaml``) holds the training schedule and, under ``study:``,
what the study needs besides: the task, the demo sources and seeds, the demo sets (episodes, operators per skill,
whether matched) and the two epochs of the table. Three stages, each resumable (rerun the same command after a
kill and it continues where it stopped):

1. :func:`build_demo_sets`: ``OUT/demos/<Task>_script`` (the oracle, at the matched pace unless natural) and
   ``OUT/demos/<Task>_human`` (simulated operators: ``operators`` novices and ``operators`` experts, each
   recording ``episodes / operators`` successful episodes, with the matched profiles unless natural), at the
   experiment's horizon; then the demo-quality table (``OUT/demos.md``, from :mod:`surrol_data.evaluation.assess`)
   beside the paper's demo figures;
2. every (source, seed) run of the study trained in this process as one batched ensemble
   (:func:`surrol_data.algos.train_batched.train_batched`) into ``OUT/runs/<source>/seed<seed>``, with the
   algo the config names (``ddpgbc``, the paper's DDPG+BC+HER, unless overridden);
3. :func:`surrol_data.evaluation.study_report.write_study_report` into ``OUT`` (report.md, report.html,
   learning_curves.png), with the demo-quality table.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import OmegaConf

from surrol_data.evaluation.report import Column, metrics_table_markdown

SKILL_OF_SOURCE = {"script": "scripted", "novice": "novice", "expert": "expert"}
# The paper's demo sets (NeedlePick, 100 episodes each): mean completion steps and tool-tip path.
PAPER_DEMOS = {"expert": (113.0, 12.1), "novice": (117.0, 12.5), "script": (109.0, 11.7)}
MATCH_TOLERANCE = 0.10
DEMO_COLUMNS = (
    Column("source", "Source"), Column("episodes", "Episodes"),
    Column("steps_to_success", "Steps to complete", lambda v: f"{v:.1f}"),
    Column("paper_steps", "Paper steps", lambda v: f"{v:.0f}"),
    Column("path_length_cm", "Path (cm)", lambda v: f"{v:.2f}"),
    Column("paper_path", "Paper path (cm)", lambda v: f"{v:.1f}"),
    Column("matched", "Within ±10 %", str),
    Column("sparc", "SPARC", lambda v: f"{v:.2f}"),
    Column("log_dimensionless_jerk", "LDLJ", lambda v: f"{v:.1f}"),
    Column("idle_time_s", "Idle (s)", lambda v: f"{v:.1f}"),
    Column("failed_grasps", "Failed grasps", lambda v: f"{v:.2f}"),
    Column("jaw_closures", "Jaw closures", lambda v: f"{v:.2f}"),
    Column("clutch_uses", "Clutch", lambda v: f"{v:.1f}"),
)


@dataclass(frozen=True)
class StudySpec:
    """What a study experiment config says under ``study:`` (see ``configs/experiment/table1.yaml``)."""
    experiment: str
    task: str = "NeedlePick"
    algo: str = "ddpgbc"
    sources: tuple[str, ...] = ("script", "novice", "expert")
    seeds: tuple[int, ...] = (0, 1, 2, 3)
    episodes: int = 100             # demos per source
    operators: int = 4              # simulated operators per skill (episodes / operators each)
    horizon: int = 150              # demo episode horizon (the paper's 150 for human NeedlePick demos)
    matched: bool = True
    report_epochs: tuple[int, ...] = (50, 100)
    run_overrides: tuple[str, ...] = field(default_factory=tuple)   # Hydra overrides of every run (from the config)
    overrides: tuple[str, ...] = field(default_factory=tuple)       # and from the command line, applied after

    def __post_init__(self):
        unknown = sorted(set(self.sources) - set(SKILL_OF_SOURCE))
        if unknown:
            raise ValueError(f"study sources {unknown} are not demo sources; choose from {sorted(SKILL_OF_SOURCE)}")
        if self.episodes < 1 or self.operators < 1 or self.episodes % self.operators:
            raise ValueError(f"study demos: {self.episodes} episodes must split evenly over {self.operators} "
                             "operators per skill (e.g. 100 = 4 × 25)")


def load_spec(experiment: str, overrides: Sequence[str] = ()) -> StudySpec:
    """The :class:`StudySpec` of ``configs/experiment/<experiment>.yaml`` (composed with ``overrides``)."""
    from hydra import compose, initialize_config_dir

    from surrol_data.train_app import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("config", overrides=[f"experiment={experiment}", *overrides])
    study = cfg.experiment.get("study")
    if study is None:
        raise ValueError(f"experiment={experiment} has no `study:` block; use a study experiment such as table1 "
                         "or table1_quick (configs/experiment/)")
    values = OmegaConf.to_container(study, resolve=True)
    for key in ("sources", "seeds", "report_epochs", "run_overrides"):
        if key in values:
            values[key] = tuple(values[key])
    return StudySpec(experiment=experiment, overrides=tuple(overrides), **values)


def operator_ids(skill: str, operators: int) -> list[str]:
    return [f"{skill}{i + 1}" for i in range(operators)]


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
    script, human = root / f"{spec.task}_script", root / f"{spec.task}_human"
    sets = {}
    if "script" in spec.sources:
        have = sum(_episode_counts(script).values())
        if have < spec.episodes:
            collect_script(spec.task, spec.episodes - have, script, seed=None, max_steps=spec.horizon,
                           append=True, progress=progress, speed=SCRIPT_SPEED_MATCHED if spec.matched else 1.0,
                           command=f"surrol-data study {spec.experiment}")
        sets["script"] = script
    per_operator = spec.episodes // spec.operators
    for skill in ("novice", "expert"):
        if skill not in spec.sources:
            continue
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
        sets[skill] = human
    return sets


def demo_quality(sets: dict[str, Path]) -> list[dict]:
    """One row per demo source: the assessment's per-skill means with the paper's demo figures beside them."""
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
        paper_steps, paper_path = PAPER_DEMOS[source]
        within = (abs(steps / paper_steps - 1) <= MATCH_TOLERANCE and abs(path_cm / paper_path - 1) <= MATCH_TOLERANCE)

        def mean(frame, col):
            v = frame[col].astype(float)
            return float(v.mean()) if v.notna().any() else math.nan

        rows.append({"source": source, "episodes": len(ep), "steps_to_success": steps, "paper_steps": paper_steps,
                     "path_length_cm": path_cm, "paper_path": paper_path, "matched": "yes" if within else "no",
                     "sparc": mean(ok, "sparc"), "log_dimensionless_jerk": mean(ok, "log_dimensionless_jerk"),
                     "idle_time_s": mean(ep, "idle_time_s"), "failed_grasps": mean(ep, "failed_grasps"),
                     "jaw_closures": mean(ep, "jaw_closures"), "clutch_uses": mean(ep, "clutch_uses")})
    return rows


def demo_quality_markdown(rows: list[dict], matched: bool) -> str:
    kind = "matched to the paper's demo sets" if matched else "natural (each operator's own pace; not matched)"
    return (f"Demo sets {kind}. Steps and path: means over successful episodes; smoothness (SPARC, LDLJ: higher is "
            "smoother) from the device trace where there is one (the simulated operators'), from the tool tip for "
            "the script; idle, failed grasps, jaw closures and clutch uses: means per episode. The human demos come "
            "from simulated operators (a motor-control model), not from people.\n\n"
            + metrics_table_markdown(rows, DEMO_COLUMNS))


def run_study(experiment: str, out: str | Path, *, natural: bool = False, overrides: Sequence[str] = (),
              progress: bool = True, command: str | None = None) -> dict[str, Path]:
    """Build the demo sets, train every (source, seed) run as one batched ensemble, write the report into ``out``.
    Returns the report's files (see :func:`surrol_data.evaluation.study_report.write_study_report`)."""
    from hydra import compose, initialize_config_dir

    from surrol_data.algos.train_batched import train_batched
    from surrol_data.evaluation.study_report import write_study_report
    from surrol_data.train_app import config_dir, to_train_config

    spec = load_spec(experiment, overrides)
    if natural:
        spec = StudySpec(**{**spec.__dict__, "matched": False})
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    sets = build_demo_sets(out / "demos", spec, progress=progress)
    demo_md = demo_quality_markdown(demo_quality(sets), spec.matched)
    (out / "demos.md").write_text(f"# Demonstrations\n\n{demo_md}")

    given = {o.split("=", 1)[0].lstrip("+~") for o in (*spec.run_overrides, *spec.overrides)}
    cfgs = []
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        for source in spec.sources:
            for seed in spec.seeds:
                base = [f"algo={spec.algo}", f"task={spec.task}", f"experiment={experiment}", f"demos={source}",
                        f"demos_root={out / 'demos'}", f"demos.num={spec.episodes}", f"seed={seed}",
                        f"run_dir={out / 'runs' / source / f'seed{seed}'}", "resume=true", "tensorboard=false",
                        f"progress={str(progress).lower()}"]
                base = [o for o in base if o.split("=", 1)[0] not in given]   # the config's and the user's win
                cfgs.append(compose("config", overrides=[*base, *spec.run_overrides, *spec.overrides]))
    train_batched([to_train_config(c) for c in cfgs], overlap=bool(cfgs[0].batched_overlap),
                  n_workers=int(cfgs[0].experiment.n_envs), progress=progress)
    natural_note = ("" if spec.matched else "\n\nThese runs use the **natural** demo sets (not matched to the paper's "
                    "demo lengths), so the comparison mixes skill with demo length.")
    notes = (f"Experiment `{experiment}`: {spec.task}, algo `{spec.algo}`, {len(spec.seeds)} seeds × "
             f"{len(spec.sources)} demo sources, {spec.episodes} demos per source ({spec.operators} simulated "
             f"operators × {spec.episodes // spec.operators} per skill), demo horizon {spec.horizon} steps. "
             "The paper's human demos came from people at a dVRK console; ours come from simulated operators "
             "driving the same device mapping, calibrated to the paper's demo lengths where matched."
             + natural_note)
    return write_study_report([out / "runs"], out, epochs=list(spec.report_epochs), demo_table_markdown=demo_md,
                              notes=notes, command=command or f"surrol-data study {experiment} --out {out}")

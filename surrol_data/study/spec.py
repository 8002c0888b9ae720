"""What a study experiment config says under ``study:``, and the fixed order of its runs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from omegaconf import OmegaConf

SKILL_OF_SOURCE = {"script": "scripted", "novice": "novice", "expert": "expert"}


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
    report_episodes: int = 100      # fresh and probed episodes per report epoch (study/report_eval.py)
    demo_dir: str | None = None            # shipped demo sets (relative to the repository); None: OUT/demos
    natural_demo_dir: str | None = None    # the same for the natural (unmatched) sets
    run_overrides: tuple[str, ...] = field(default_factory=tuple)   # Hydra overrides of every run (from the config)
    overrides: tuple[str, ...] = field(default_factory=tuple)       # and from the command line, applied after

    def __post_init__(self):
        unknown = sorted(set(self.sources) - set(SKILL_OF_SOURCE))
        if unknown:
            raise ValueError(f"study sources {unknown} are not demo sources; choose from {sorted(SKILL_OF_SOURCE)}")
        if self.episodes < 1 or self.operators < 1 or self.episodes % self.operators:
            raise ValueError(f"study demos: {self.episodes} episodes must split evenly over {self.operators} "
                             "operators per skill (e.g. 100 = 4 × 25)")

    def run_order(self) -> list[tuple[str, int]]:
        """Every (source, seed) run, seeds outermost: any prefix of the order has every source within one seed
        of the others, so a partial study stays balanced."""
        return [(source, seed) for seed in self.seeds for source in self.sources]

    def shipped_demo_dir(self) -> str | None:
        return self.demo_dir if self.matched else self.natural_demo_dir


def run_name(source: str, seed: int) -> str:
    return f"{source}/{seed}"


def parse_runs(text: str, spec: StudySpec) -> list[tuple[str, int]]:
    """``expert/0,novice/1`` → [(expert, 0), (novice, 1)], each checked against the study's sources and seeds."""
    runs = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        source, _, seed = part.partition("/")
        if not seed.strip().isdigit():
            raise ValueError(f"--runs takes SOURCE/SEED items separated by commas, e.g. expert/0,novice/1; got {part!r}")
        run = (source.strip(), int(seed))
        if run not in spec.run_order():
            raise ValueError(f"{part!r} is not a run of study {spec.experiment}: its runs are "
                             f"{', '.join(run_name(*r) for r in spec.run_order())}")
        if run not in runs:
            runs.append(run)
    if not runs:
        raise ValueError("--runs names no run; e.g. --runs expert/0,novice/1")
    return runs


def load_spec(experiment: str, overrides: Sequence[str] = ()) -> StudySpec:
    """The :class:`StudySpec` of ``configs/experiment/<experiment>.yaml`` (composed with ``overrides``)."""
    values = experiment_block(experiment, "study", overrides, "a study experiment such as table1 or table1_quick")
    for key in ("sources", "seeds", "report_epochs", "run_overrides"):
        if key in values:
            values[key] = tuple(values[key])
    return StudySpec(experiment=experiment, overrides=tuple(overrides), **values)


def experiment_block(experiment: str, block: str, overrides: Sequence[str] = (), example: str = "") -> dict:
    """The ``block:`` of ``configs/experiment/<experiment>.yaml`` (composed with ``overrides``) as a plain dict."""
    from hydra import compose, initialize_config_dir

    from surrol_data.train_app import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("config", overrides=[f"experiment={experiment}", *overrides])
    values = cfg.experiment.get(block)
    if values is None:
        raise ValueError(f"experiment={experiment} has no `{block}:` block; use {example} (configs/experiment/)")
    return OmegaConf.to_container(values, resolve=True)


def operator_ids(skill: str, operators: int) -> list[str]:
    return [f"{skill}{i + 1}" for i in range(operators)]

"""Every ``surrol-data`` command of the README and the docs pages runs as written — with small sizes (at most 20
collected and 5 evaluation episodes, training on ``experiment=smoke``, a study on ``table1_quick``), in a scratch
folder, each ``bash`` block in order: the README's, then each page of ``DOC_PAGES`` in turn. A command an earlier
block already ran in the same folder (a docs page repeating the README) is not run again.

Left out: the install lines (``pip install uv``, the test suite itself), the SLURM commands (no cluster
here: ``tests/test_slurm.py`` starts one and runs them; the sweep's composed config is still checked with
``--cfg job``) and ``eval --policy lerobot:DIR`` (it needs a
``lerobot-train`` run first; ``tests/test_lerobot_train.py`` runs the two in order).
"""

from __future__ import annotations

import itertools
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from surrol_data.render.display import unavailable_reason as panda3d_unavailable

REPO_ROOT = Path(__file__).resolve().parents[1]
CAP = {"collect": 20, "eval": 5}  # --num-episodes at most (20 keeps `split --valid-fraction 0.1` meaningful)


_OUTPUTS = itertools.count()


# The docs pages whose commands run after the README's, in this order (later pages use what earlier ones made).
DOC_PAGES = ("index.md", "quickstart.md", "envs.md", "physics.md", "teleoperation.md", "web_console.md", "datasets.md",
             "training.md", "interventions.md", "evaluation.md", "rendering.md", "benchmarks.md", "architecture.md",
             "api.md")
# Where a command may write: git-ignored folders, the study's results, the user's home. Never the repository root.
OUTPUT_ROOTS = ("outputs/", "datasets/", "runs/", "docs/results/", "~/")


def doc_files() -> list[Path]:
    """README.md, then the docs pages in ``DOC_PAGES`` order."""
    return [REPO_ROOT / "README.md", *(REPO_ROOT / "docs" / name for name in DOC_PAGES)]


def bash_blocks(path: Path) -> list[list[str]]:
    """The ``uv run surrol-data`` commands of each ```bash block of one Markdown file (continuation lines joined,
    comments cut)."""
    text = path.read_text()
    blocks = []
    for body in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        commands = []
        for line in body.replace("\\\n", " ").splitlines():
            line = re.split(r"\s#", line)[0].strip()  # a comment starts at " #", however many spaces precede it
            if "surrol-data" in line and "pip install" not in line:
                commands.append(line[line.index("surrol-data"):])
        if commands:
            blocks.append(commands)
    return blocks


def readme_blocks() -> list[list[str]]:
    """The commands of each ```bash block of README.md."""
    return bash_blocks(REPO_ROOT / "README.md")


def all_blocks() -> list[list[str]]:
    """The commands of each ```bash block of README.md, then of each docs page in ``DOC_PAGES`` order."""
    return [block for path in doc_files() for block in bash_blocks(path)]


def adapt(command: str, home: Path) -> list[str] | None:
    """A README or docs command with small sizes and placeholders filled; None if it cannot run here."""
    args = shlex.split(command.replace("~", str(home)))
    if "hydra/launcher=slurm" in args or "slurm" in args:   # tests/test_slurm.py runs these on a local SLURM
        return None
    if args[1] == "serve":   # the web console serves until stopped: tests/test_web_console.py runs it
        return None
    if any(a.startswith("lerobot:") for a in args):   # needs lerobot-train's output first: tests/test_lerobot_train.py
        return None
    if "panda3d" in args and panda3d_unavailable() is not None:   # no EGL here: tests/test_render_panda3d.py skips too
        return None
    if args[1] == "train" and "--cfg" not in args:
        args.append("experiment=smoke")
    if args[1] == "study":   # the Table I study takes hours: the same pipeline on its tiny config, one seed
        args[2] = "table1_quick"
        args += ["--override", "experiment.study.seeds=[0]"]
    if args[1] == "interventions":   # the demos-or-interventions experiment takes an hour: one tiny round
        args += [x for k in ("tasks=[NeedleReach]", "seeds=[0]", "base_demos=1", "rounds=1", "rollouts_per_round=1",
                             "eval_episodes=1", "bc_epochs=1", "bc_steps_per_epoch=5")
                 for x in ("--override", f"experiment.interventions.{k}")]
    if args[1] == "demo":
        args += ["--out", f"demo_out_{next(_OUTPUTS)}", "--num-episodes", "3", "--eval-episodes", "2"]
    for i, arg in enumerate(args[:-1]):
        if arg in ("--num-episodes", "--episodes") and args[1] in CAP:
            args[i + 1] = str(min(int(args[i + 1]), CAP[args[1]]))
    filled = []
    for arg in args:
        if arg == "DIR":
            filled.append("datasets/NeedlePick_human")
        elif arg in ("DIR1", "DIR2"):
            filled.append({"DIR1": "datasets/NeedlePick_script", "DIR2": "datasets/NeedlePick_human"}[arg])
        elif arg == "...":
            continue
        elif arg == "OUT":  # numbered: the README may write with one command twice (e.g. two filter examples)
            filled.append(f"out_{args[1]}_{next(_OUTPUTS)}")
        else:
            filled.append(arg)
    return filled


@pytest.mark.slow
def test_readme_commands_run_as_written(tmp_path):
    exe = Path(sys.executable).parent / "surrol-data"
    env = {**os.environ, "HOME": str(tmp_path / "home"), "HF_HUB_OFFLINE": "1"}
    (tmp_path / "home").mkdir()
    first = tmp_path / "work"
    first.mkdir()
    failures = []
    done = set()
    for n, block in enumerate(all_blocks()):
        cwd = first
        if any("collect" in c and "NeedlePick_script" in c for c in block) and (first / "datasets").exists():
            # a block that records its own datasets again starts from a fresh folder (keeping the human demos)
            cwd = tmp_path / f"block{n}"
            cwd.mkdir()
            if (first / "datasets" / "NeedlePick_human").exists():
                shutil.copytree(first / "datasets" / "NeedlePick_human", cwd / "datasets" / "NeedlePick_human")
        for command in block:
            args = adapt(command, tmp_path / "home")
            if args is None or (cwd, tuple(args)) in done:
                continue
            done.add((cwd, tuple(args)))
            run = subprocess.run([str(exe), *args[1:]], cwd=cwd, env=env, capture_output=True, text=True,
                                 timeout=1200)
            if run.returncode != 0 or "Traceback" in run.stderr or "Exception ignored" in run.stderr:
                failures.append(f"{' '.join(args)} (exit {run.returncode}): {run.stderr[-1500:]}")
    assert not failures, "\n\n".join(failures)


def test_every_docs_page_is_listed():
    """A new docs page must join ``DOC_PAGES`` (and so the run above), or its commands would go untested."""
    pages = {p.name for p in (REPO_ROOT / "docs").glob("*.md")}
    assert pages == set(DOC_PAGES), f"docs pages not in DOC_PAGES: {sorted(pages - set(DOC_PAGES))}; " \
                                    f"listed but missing: {sorted(set(DOC_PAGES) - pages)}"


def test_commands_are_found_and_placeholders_known():
    """The parser finds the README's and the pages' commands, and every argument it fills in is one it knows."""
    blocks = all_blocks()
    commands = [c for block in blocks for c in block]
    assert readme_blocks() and blocks[:len(readme_blocks())] == readme_blocks()
    assert any(c.startswith("surrol-data collect") for c in commands)
    assert len(blocks) > len(readme_blocks()), "the docs pages' commands are not found"
    for command in commands:
        args = adapt(command, Path("/home/x"))
        if args is not None:   # a placeholder such as FILE or TASK left in would fail only in the slow run
            assert not any(a.isupper() and a.isalpha() for a in args), command


def test_commands_write_under_output_folders():
    """What a README or docs command writes (``--out``, ``--screenshot``) goes under ``outputs/`` (git-ignored),
    ``datasets/``, ``runs/`` or the study's ``docs/results/`` — never loose in the repository root."""
    stray = []
    for path in doc_files():
        for block in bash_blocks(path):
            for command in block:
                args = shlex.split(command)
                for flag, value in zip(args, args[1:]):
                    if flag in ("--out", "--screenshot") and value not in ("OUT",) \
                            and not value.startswith(OUTPUT_ROOTS):
                        stray.append(f"{path.name}: {command}")
    assert not stray, "\n".join(stray)

"""The Table I study report on real (tiny) training runs: files, table layout, self-contained HTML."""

import shutil
import subprocess

import pytest

from surrol_data.algos.demos import DemoSpec
from surrol_data.algos.train import Schedule, TrainConfig, train
from surrol_data.evaluation.study_report import (PAPER_TABLE1, StudyReportError, demo_source, discover_runs,
                                                 report_epochs, table1_estimates, write_study_report)

REACH = "SurRoL/NeedleReach-v0"


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """Two short NeedleReach runs: one from script demos, one without demos."""
    from surrol_data.collect.script_source import collect_script

    root = tmp_path_factory.mktemp("study")
    demos = root / "NeedleReach_script"
    collect_script("NeedleReach", 4, demos, progress=False)
    schedule = Schedule(epochs=2, cycles=1, episodes_per_cycle=2, updates_per_cycle=2, n_envs=1, eval_episodes=2,
                        offline_steps=5, buffer_episodes=10)
    for name, spec in (("script", DemoSpec(path=str(demos), where={"source": "script"}, num=4)),
                       ("none", DemoSpec(path=None))):
        train(TrainConfig(env_id=REACH, run_dir=str(root / "runs" / name / "seed0"), learner="ddpg",
                          learner_params={"hidden_sizes": (16, 16)}, demos=spec, schedule=schedule,
                          progress=False, tensorboard=False))
    return root / "runs"


def test_report_writes_markdown_html_and_curves(two_runs, tmp_path):
    paths = write_study_report([two_runs], tmp_path / "report", command="surrol-data report runs --out report")
    md = paths["markdown"].read_text()
    assert paths["curves"].stat().st_size > 10_000          # a real PNG with three panels
    # Table I layout: three metric rows per epoch, ours beside the paper's for each source
    header = next(line for line in md.splitlines() if line.startswith("| Metric"))
    assert header == "| Metric | Epoch | script (ours) | script (paper) | none (ours) | none (paper) |"
    assert md.count("| Success rate (%) |") == 2 and md.count("| Economy of motion (cm) |") == 2
    assert "surrol-data report runs --out report" in md and "commit" in md
    html = paths["html"].read_text()
    assert html.startswith("<!DOCTYPE html>") and "data:image/png;base64," in html
    assert 'src="learning_curves.png"' not in html          # self-contained: the figure is embedded
    assert "<table>" in html and "script (ours)" in html


def test_table_uses_the_papers_epochs_and_figures(two_runs):
    runs = discover_runs([two_runs])
    assert {r.source for r in runs} == {"script", "none"} and all(r.task == "NeedleReach" for r in runs)
    assert report_epochs(runs) == (1, 2)                   # short runs: half and all
    assert report_epochs(runs, [50, 100]) == (50, 100)
    est = table1_estimates(runs, [2, 99])
    assert est[2]["success_rate"]["script"].n == 1
    assert est[99]["success_rate"]["script"].n == 0 and est[99]["success_rate"]["script"].format() == "–"
    assert PAPER_TABLE1[50]["success_rate"]["expert"] == (89.7, 6.4)


def test_demo_source_names_and_clear_errors(tmp_path):
    assert demo_source({"path": "d/NeedlePick_human", "where": {"skill": "novice"}}) == "novice"
    assert demo_source({"path": "d/NeedlePick_script", "where": {"source": "script"}}) == "script"
    assert demo_source({"path": None}) == "none"
    with pytest.raises(StudyReportError, match="no training runs"):
        discover_runs([tmp_path])
    with pytest.raises(StudyReportError, match="does not exist"):
        discover_runs([tmp_path / "missing"])


@pytest.mark.browser
def test_report_html_renders_in_headless_chromium_without_console_errors(two_runs, tmp_path):
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("needs headless Chromium: apt-get install chromium")
    paths = write_study_report([two_runs], tmp_path / "report")
    shot = tmp_path / "shot.png"
    out = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr",
                          "--v=0", f"--screenshot={shot}", "--window-size=1200,1600",
                          paths["html"].resolve().as_uri()], capture_output=True, text=True, timeout=120)
    assert shot.is_file() and shot.stat().st_size > 10_000
    console_errors = [line for line in out.stderr.splitlines() if "CONSOLE" in line and "ERROR" in line.upper()]
    assert not console_errors, console_errors

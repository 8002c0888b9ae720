"""The Table I study run by run: a partial study's report, run folders, code identity, the shipped demo sets."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from surrol_data.algos.ddpg import DDPGConfig
from surrol_data.algos.fingerprint import learner_fingerprint
from surrol_data.datasets.metrics import first_grasp_failed
from surrol_data.evaluation.code_identity import CodeIdentity, CodeIdentityError, check_same_code
from surrol_data.evaluation.study_report import StudyReportError, write_study_report
from surrol_data.study.spec import load_spec, parse_runs

REPO = Path(__file__).resolve().parents[1]


def _ident(commit="a" * 40, cpu="cpu A", env="e1", learner="l1", dirty=False, config="c1"):
    return CodeIdentity(commit=commit, dirty=dirty, cpu=cpu, env_fingerprint=env, learner_fingerprint=learner,
                        config_fingerprint=config)


def test_run_order_interleaves_sources_and_seeds():
    spec = load_spec("table1")
    order = spec.run_order()
    assert len(order) == 12 and order[:4] == [("script", 0), ("novice", 0), ("expert", 0), ("script", 1)]
    assert parse_runs("expert/0, novice/1", spec) == [("expert", 0), ("novice", 1)]
    with pytest.raises(ValueError, match="not a run of study table1"):
        parse_runs("expert/7", spec)
    with pytest.raises(ValueError, match="SOURCE/SEED"):
        parse_runs("expert", spec)


def test_same_code_means_equal_fingerprints_on_one_cpu_or_one_clean_commit():
    check_same_code({"a": _ident(), "b": _ident()})
    # another CPU's bits differ, but the same clean commit is the same code
    check_same_code({"a": _ident(), "b": _ident(cpu="cpu B", env="e9", learner="l9")})
    # same CPU, different behaviour: refused whatever the commits
    with pytest.raises(CodeIdentityError, match="behaves differently on the same CPU"):
        check_same_code({"a": _ident(), "b": _ident(commit="b" * 40, env="e2")})
    # another CPU at another commit: not shown to be the same ...
    other = _ident(commit="b" * 40, cpu="cpu B", env="e9", learner="l9")
    with pytest.raises(CodeIdentityError, match="cannot be shown to run the same code"):
        check_same_code({"a": _ident(), "b": other})
    # ... until a before/after check on cpu B links the old commit to cpu B's fingerprints
    check_same_code({"a": _ident(), "b": other}, [_ident(cpu="cpu B", env="e9", learner="l9")])
    # uncommitted changes: the commit says nothing about the code
    with pytest.raises(CodeIdentityError, match="cannot be shown"):
        check_same_code({"a": _ident(), "b": _ident(cpu="cpu B", env="e9", dirty=True)})
    with pytest.raises(CodeIdentityError, match="another training config"):
        check_same_code({"a": _ident(), "b": _ident(config="c2")})


def test_learner_fingerprint_is_repeatable_and_sees_a_changed_loss():
    def reward(ag, g):
        return -(np.linalg.norm(np.asarray(ag) - np.asarray(g), axis=-1) > 0.01).astype(np.float32)

    cfg = DDPGConfig(hidden_sizes=(32, 32), q_filter=False, action_l2=0.0)
    first = learner_fingerprint(cfg, 7, 3, 5, reward, 4)
    assert learner_fingerprint(cfg, 7, 3, 5, reward, 4) == first
    assert learner_fingerprint(DDPGConfig(hidden_sizes=(32, 32), q_filter=False, action_l2=0.0, bc_weight=4.0),
                               7, 3, 5, reward, 4) != first
    assert learner_fingerprint(cfg, 7, 3, 5, reward, 2) != first          # HER relabelling ratio


def test_fingerprints_are_the_same_in_every_process():
    """A fingerprint must not hash memory addresses (numpy holds None and other objects as pointers)."""
    import subprocess
    import sys

    code = ("import hashlib, numpy as np; from surrol_data.envs.fingerprint import feed; h = hashlib.sha256(); "
            "feed(h, {'noise': np.arange(3.0), 'replace': None, 'random': [None, 1]}); print(h.hexdigest())")
    digests = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
               for _ in range(2)}
    assert len(digests) == 1
    from surrol_data.envs.fingerprint import feed

    with pytest.raises(TypeError, match="cannot fingerprint"):
        feed(__import__("hashlib").sha256(), object())


def test_first_grasp_failed_and_recovery_inputs():
    jaw = np.array([1, -1, -1, 1, -1, -1, 1], float)
    assert first_grasp_failed(jaw, np.array([0, 0, 0, 0, 1, 1, 0], bool)) is True
    assert first_grasp_failed(jaw, np.array([0, 0, 1, 1, 1, 1, 0], bool)) is False
    assert first_grasp_failed(np.ones(5), np.zeros(5, bool)) is None


@pytest.fixture(scope="module")
def partial_study(table1_quick_partial):
    """table1_quick (3 sources × 2 seeds, tiny), its first two runs trained by `study --next 2` (conftest: one per
    session, shared with the notebook test that reads it)."""
    return table1_quick_partial


def test_a_partial_study_commits_run_folders_and_a_report_marked_partial(partial_study):
    out = partial_study
    runs = sorted(p.parent.relative_to(out / "runs").as_posix() for p in (out / "runs").rglob("run.json"))
    assert runs == ["novice/seed0", "script/seed0"]            # the first two of the interleaved order
    assert not (out / ".work").exists()                          # checkpoints gone once the runs finished
    folder = out / "runs" / "script" / "seed0"
    for name in ("metrics.csv", "metrics.jsonl", "eval_episodes.csv", "report_episodes.csv", "policy.pt",
                 "config.yaml", "config.json"):
        assert (folder / name).is_file(), name
    record = json.loads((folder / "run.json").read_text())
    assert record["source"] == "script" and record["seed"] == 0 and record["epochs"] == 2
    assert len(record["code"]["env_fingerprint"]) == 64 and len(record["code"]["learner_fingerprint"]) == 64
    assert record["demos"]["dataset"] == "NeedlePick_script" and len(record["demos"]["sha256"]) == 64
    assert record["time"]["cpu_s"] > 0 and record["time"]["batched_members"] == 2
    episodes = pd.read_csv(folder / "eval_episodes.csv")
    assert sorted(episodes["epoch"].unique()) == [1, 2]          # the report epochs of table1_quick
    assert {"final_success", "failed_grasps", "attempts", "retries", "attempt_outcome"} <= set(episodes.columns)
    # the report epochs' kept actors on fresh episodes and under the probe (table1_quick: 2 of each per epoch)
    report_eps = pd.read_csv(folder / "report_episodes.csv")
    assert sorted(report_eps.groupby(["epoch", "kind"]).size().items()) == \
        [((1, "eval"), 2), ((1, "probe"), 2), ((2, "eval"), 2), ((2, "probe"), 2)]
    assert report_eps["seed"].min() >= 2_000_000_000                  # disjoint from demos, training, per-epoch eval
    assert {"probed", "attempt_outcome", "steps_to_success"} <= set(report_eps.columns)
    report = (out / "report.md").read_text()
    assert "(partial)" in report and "stands on 2 of the study's 6 runs" in report
    assert "Missing: expert/0, script/1, novice/1, expert/1" in report
    assert "Table I stands on epoch 1: 2 run(s) on their kept actor's evaluation of 2 fresh episodes" in report
    assert report.count("| Steps to complete (successes only) |") == 2
    assert report.count("| Steps to complete (failures at the horizon) |") == 2
    assert "## Attempts and recovery" in report and "| First attempt held |" in report
    assert "jaw flicker away from the needle is no attempt" in report   # what the counts mean
    assert "## Induced failure: the first attempt made to fail" in report and "| First attempt disabled |" in report
    assert "Not in the table" not in report      # every run has both records
    # the report names the command that rebuilds it, not the training command that last wrote it
    assert f"Report command: `surrol-data study table1_quick --out {out} --report`" in report


def test_the_kept_actors_are_written_and_load(partial_study):
    from surrol_data.algos.policies import load_policy

    folder = partial_study / "runs" / "novice" / "seed0" / "actors"
    assert sorted(p.name for p in folder.iterdir()) == ["epoch001.pt", "epoch002.pt"]   # table1_quick's 2 epochs
    final = load_policy(partial_study / "runs" / "novice" / "seed0" / "policy.pt")
    last = load_policy(folder / "epoch002.pt")
    obs = {"observation": np.linspace(0, 1, 19, dtype=np.float32), "desired_goal": np.zeros(3, np.float32),
           "achieved_goal": np.zeros(3, np.float32)}
    np.testing.assert_array_equal(last(obs), final(obs))   # the last kept actor is the final one


def test_the_final_policy_of_a_run_evaluates(partial_study):
    from typer.testing import CliRunner

    from surrol_data.cli import app

    policy = partial_study / "runs" / "novice" / "seed0" / "policy.pt"
    result = CliRunner().invoke(app, ["eval", "--task", "NeedlePick", "--policy", str(policy), "--num-episodes", "1"])
    assert result.exit_code == 0, result.output


def test_a_run_whose_recorded_code_differs_is_refused(partial_study, tmp_path):
    import shutil

    from typer.testing import CliRunner

    from surrol_data.cli import app

    copy = tmp_path / "study"
    shutil.copytree(partial_study, copy)
    record_path = copy / "runs" / "novice" / "seed0" / "run.json"
    record = json.loads(record_path.read_text())
    record["code"]["env_fingerprint"] = "0" * 64            # as if the env had changed between the two runs
    record_path.write_text(json.dumps(record))
    with pytest.raises(StudyReportError, match="behaves differently on the same CPU"):
        write_study_report([copy / "runs"], tmp_path / "report")
    # and the study refuses to train more runs beside them
    result = CliRunner().invoke(app, ["study", "table1_quick", "--out", str(copy), "--report"])
    assert result.exit_code != 0 and "behaves differently" in result.output


@pytest.mark.parametrize("natural", [False, True], ids=["matched", "natural"])
def test_shipped_demo_sets_validate_and_hash_as_recorded(natural):
    from dataclasses import replace

    from surrol_data.datasets.validate import validate_dataset
    from surrol_data.study.demo_sets import MANIFEST, check_shipped, set_paths

    spec = load_spec("table1")
    spec = replace(spec, matched=not natural)
    root = REPO / spec.shipped_demo_dir()
    if natural and not (root / MANIFEST).is_file():
        pytest.skip(f"the natural demo sets are not shipped yet ({root}): the study builds them before its natural runs")
    hashes = check_shipped(root, spec)
    manifest = json.loads((root / MANIFEST).read_text())
    assert hashes == {name: entry["sha256"] for name, entry in manifest["sets"].items()}
    for path in dict.fromkeys(set_paths(root, spec).values()):
        problems = validate_dataset(path)
        assert problems == [], [str(p) for p in problems]


def test_a_batch_split_resumes_its_runs_and_shares_their_cpu_by_batch_size(tmp_path):
    """Runs of a killed batch of 3, resumed as a batch of 2: their checkpoints are kept, each epoch's ensemble CPU
    is divided by that epoch's batch size; a batch whose runs lack checkpoints starts afresh."""
    import shutil

    from surrol_data.study.runs import _cpu_share, _start_batch

    work = tmp_path / ".work"
    names = ["script/0", "novice/0", "expert/0"]
    for name in names:
        folder = work / name.split("/")[0] / f"seed{name.split('/')[1]}"
        folder.mkdir(parents=True)
        (folder / "checkpoint.pt").write_bytes(b"x")
        (folder / "metrics.jsonl").write_text("".join(json.dumps({"epoch": e}) + "\n" for e in range(5)))
    (work / "batch.json").write_text(json.dumps(names))
    _start_batch(tmp_path, names[:2])
    history = json.loads((work / "script" / "seed0" / "batches.json").read_text())
    assert history == [{"from_epoch": 0, "members": 3}, {"from_epoch": 5, "members": 2}]
    assert (work / "novice" / "seed0" / "checkpoint.pt").is_file()      # kept: the pair resumes
    rows = [{"epoch": e, "time_cpu_learner_s": 6.0, "time_cpu_envs_s": 6.0} for e in range(7)]
    assert _cpu_share(rows, history) == pytest.approx(5 * 12 / 3 + 2 * 12 / 2)
    assert _cpu_share([{**rows[0], "batched_members": 4}], history) == pytest.approx(3.0)
    # the pair finishing leaves the third run's checkpoints for later
    from surrol_data.study.runs import _end_batch

    for name in ("script", "novice"):
        shutil.rmtree(work / name)            # _finish_run moved them into runs/
    _end_batch(tmp_path)
    assert (work / "expert" / "seed0" / "checkpoint.pt").is_file() and not (work / "batch.json").exists()
    # a new batch with a run that has no checkpoint starts every one of its runs afresh
    _start_batch(tmp_path, ["expert/0", "script/1"])
    assert not (work / "expert" / "seed0" / "checkpoint.pt").exists()
    assert json.loads((work / "expert" / "seed0" / "batches.json").read_text()) == [{"from_epoch": 0, "members": 2}]


def test_the_rebuild_command_names_the_report_relative_to_its_repository(tmp_path, monkeypatch):
    """A batch trained from another worktree (or a check run from anywhere) still records the command as it reads
    in the repository that holds the report, not this machine's absolute path."""
    from surrol_data.study.runs import _rebuild_command

    repo = tmp_path / "repo"
    (repo / ".git").mkdir(parents=True)
    elsewhere = tmp_path / "worktree"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert _rebuild_command("table1", repo / "docs" / "results" / "table1", False) == \
        "surrol-data study table1 --out docs/results/table1 --report"
    assert _rebuild_command("table1", repo / "docs" / "results" / "table1_natural", True) == \
        "surrol-data study table1 --out docs/results/table1_natural --natural --report"

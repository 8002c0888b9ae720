"""Learning from interventions: frame-level demo selection (HG-DAgger's takeover segments, DDPG+BC+HER's demo buffer)
and the demos-or-interventions experiment, end to end at a tiny size.

Real components: the PyBullet tasks, the simulated supervisor, the real ``lerobot`` dataset writer and reader, BC and
the DDPG+BC+HER trainer through the Hydra app.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from surrol_data.algos.demos import DemoSpec, load_demos, select_frames
from surrol_data.algos.train import TrainConfig, _config_json
from surrol_data.cli import app
from surrol_data.datasets.interventions import takeover_spans, trajectory_span
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.trajectory import INTERVENTION, Trajectory

TASK = "NeedleReach"    # 7-D observation, no object: supervised episodes take seconds


def _trajectory(n: int, intervention=None) -> Trajectory:
    rng = np.random.default_rng(n)
    flags = {} if intervention is None else {INTERVENTION: np.asarray(intervention, bool).reshape(n, -1)}
    return Trajectory(
        observation=np.arange(n + 1, dtype=np.float32)[:, None].repeat(7, 1), achieved_goal=rng.random((n + 1, 3)),
        desired_goal=rng.random((n + 1, 3)), action=np.arange(n, dtype=np.float32)[:, None].repeat(5, 1) / n,
        reward=np.zeros(n, np.float32), success=np.zeros(n, bool), terminated=np.zeros(n, bool),
        tip_position=np.zeros((n + 1, 1, 3), np.float32), jaw_angle=np.zeros((n + 1, 1), np.float32), flags=flags,
        policy_action=None if intervention is None else np.zeros((n, 5), np.float32))


def test_takeover_spans_are_the_runs_of_frames_any_arm_was_driven():
    assert takeover_spans(np.array([0, 1, 1, 0, 0, 1], bool)) == [(1, 3), (5, 6)]
    two_arms = np.array([[0, 0], [1, 0], [0, 1], [0, 0], [1, 1]], bool)
    assert takeover_spans(two_arms) == [(1, 3), (4, 5)]
    assert takeover_spans(np.zeros(4, bool)) == []


def test_a_span_is_a_trajectory_of_its_own_with_the_observation_after_its_last_action():
    traj = _trajectory(6, [0, 0, 1, 1, 0, 0])
    part = trajectory_span(traj, 2, 4)
    assert len(part) == 2 and part.observation[:, 0].tolist() == [2, 3, 4]
    assert np.array_equal(part.action, traj.action[2:4]) and part.flags[INTERVENTION].all()
    with pytest.raises(ValueError, match="not within"):
        trajectory_span(traj, 4, 9)


def test_frame_selection_keeps_whole_demos_and_takeover_segments():
    demo, session = _trajectory(5), _trajectory(8, [0, 1, 1, 0, 0, 1, 1, 1])
    everything, eps = select_frames([demo, session], [3, 4], "all")
    assert everything == [demo, session] and eps == [3, 4]
    human, eps = select_frames([demo, session], [3, 4], "human")
    assert [len(t) for t in human] == [5, 2, 3] and eps == [3, 4, 4]
    takeovers, eps = select_frames([demo, session], [3, 4], "intervention")
    assert [len(t) for t in takeovers] == [2, 3] and eps == [4, 4]
    with pytest.raises(ValueError, match="demos.frames must be one of"):
        select_frames([demo], [0], "takeover")


def test_the_default_frame_selection_leaves_the_recorded_training_config_as_it_was():
    """Runs recorded before frame selection existed (the Table I study) resume and fingerprint the same: the
    default stays out of the config a run records and compares on resume."""
    cfg = TrainConfig(env_id="SurRoL/NeedlePick-v0", run_dir="r")
    assert set(_config_json(cfg)["demos"]) == {"path", "where", "num", "successful_only"}
    cfg.demos = DemoSpec(path="d", frames="human")
    assert _config_json(cfg)["demos"]["frames"] == "human"


def _invoke(args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    return result, " ".join(result.output.split())


TINY = [f"experiment.interventions.{k}" for k in (
    f"tasks=[{TASK}]", "seeds=[0,1]", "base_demos=1", "rounds=1", "rollouts_per_round=2", "eval_episodes=2",
    "bc_epochs=1", "bc_steps_per_epoch=5")]


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    out = tmp_path_factory.mktemp("interventions") / "out"
    args = ["interventions", "--out", out, *[x for o in TINY for x in ("--override", o)]]
    result, text = _invoke(args)
    assert result.exit_code == 0, result.output
    return out, args, text


def test_the_experiment_runs_end_to_end_and_reports_success_against_human_frames(experiment):
    out, _, text = experiment
    assert "wrote" in text
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert sorted((r["seed"], r["arm"], r["round"]) for r in rows) == sorted(
        (s, a, r) for s in (0, 1) for a in ("interventions", "demos") for r in (0, 1))
    for seed in (0, 1):
        mine = {(r["arm"], r["round"]): r for r in rows if r["seed"] == seed}
        # Round 0 is one policy for both arms; afterwards each arm's human effort grew, the demos' to at least the
        # interventions' (whole demos are added until they hold as many frames as the operator drove).
        assert mine["interventions", 0]["human_frames"] == mine["demos", 0]["human_frames"]
        taken = mine["interventions", 1]["human_frames"] - mine["interventions", 0]["human_frames"]
        assert taken > 0, "the supervisor never took over the weak policy"
        assert mine["demos", 1]["human_frames"] >= mine["interventions", 1]["human_frames"]
        assert mine["interventions", 1]["supervised_frames"] >= taken
        round1 = DatasetReader(out / "work" / TASK / f"seed{seed}" / "round1")
        assert len(round1.episodes) == 2 and set(round1.episodes["source"]) == {"intervention"}
    report = (out / "report.md").read_text()
    assert f"## {TASK}" in report and "bootstrap 95 % interval" in report
    table = [line for line in report.splitlines() if line.startswith("| 1 |")]
    assert len(table) == 1 and "–" not in table[0]
    assert (out / "success_vs_effort.png").stat().st_size > 5000
    html = (out / "report.html").read_text()
    assert "data:image/png;base64" in html and TASK in html


def _rows(folder, seeds=(0, 1)):
    """What was measured, per row (the CPU seconds it took differ run to run)."""
    return sorted(json.dumps({k: v for k, v in row.items() if not k.endswith("cpu_s")}, sort_keys=True)
                  for row in map(json.loads, (folder / "results.jsonl").read_text().splitlines())
                  if row["seed"] in seeds)


def test_a_cell_in_a_worker_process_gives_the_rows_it_gives_in_process(experiment, tmp_path):
    """--workers > 1 runs each cell in a spawned process: one cell (seed 1) there gives the in-process rows. (Two
    cells in two processes at once, appending to one results.jsonl: the slow test below.)"""
    out, args, _ = experiment
    worker = tmp_path / "worker"
    args = [worker if a == out else "experiment.interventions.seeds=[1]" if str(a).endswith("seeds=[0,1]") else a
            for a in args]
    assert "experiment.interventions.seeds=[1]" in args
    result, text = _invoke([*args, "--workers", 2])
    assert result.exit_code == 0, result.output
    assert f"{TASK} seed 1: done" in text and f"{TASK} seed 0" not in text
    assert _rows(worker) == _rows(out, seeds=(1,)) and _rows(worker)


@pytest.mark.slow
def test_cells_in_parallel_processes_give_the_same_rows(experiment, tmp_path):
    out, args, _ = experiment
    parallel = tmp_path / "parallel"
    result, text = _invoke([*[parallel if a == out else a for a in args], "--workers", 2])
    assert result.exit_code == 0, result.output
    assert f"{TASK} seed 0: done" in text and f"{TASK} seed 1: done" in text
    assert _rows(parallel) == _rows(out)


def test_a_rerun_continues_and_redoes_nothing_and_another_config_is_refused(experiment):
    out, args, _ = experiment
    before = (out / "results.jsonl").read_text()
    stamps = {p: p.stat().st_mtime_ns for p in (out / "work").rglob("*.pt")}
    result, _ = _invoke(args)
    assert result.exit_code == 0, result.output
    assert (out / "results.jsonl").read_text() == before
    assert {p: p.stat().st_mtime_ns for p in (out / "work").rglob("*.pt")} == stamps
    result, text = _invoke([*args, "--override", "experiment.interventions.rounds=2"])
    assert result.exit_code != 0 and "another configuration" in text and "Traceback" not in result.output


def test_hg_dagger_bc_trains_on_the_takeover_frames_from_the_cli(experiment, tmp_path):
    out, _, _ = experiment
    dataset = out / "work" / TASK / "seed0" / "round1"
    trajs, eps = load_demos(DemoSpec(path=str(dataset), num=2, successful_only=False, frames="intervention"))
    frames = sum(len(t) for t in trajs)
    assert frames > 0 and all(t.flags[INTERVENTION].any(axis=1).all() for t in trajs)
    result, text = _invoke(["train-bc", dataset, "--out", tmp_path / "p.pt", "--epochs", 1, "--steps-per-epoch", 2,
                            "--no-successful-only", "--frames", "intervention"])
    assert result.exit_code == 0, result.output
    assert f"({frames} samples)" in text
    result, text = _invoke(["train-bc", dataset, "--out", tmp_path / "q.pt", "--frames", "takeovers"])
    assert result.exit_code != 0 and "--frames must be one of" in text


def test_ddpg_bc_her_fills_its_demo_buffer_with_takeover_segments_and_resumes(experiment, tmp_path, capsys):
    from surrol_data.train_app import main

    out, _, _ = experiment
    dataset = out / "work" / TASK / "seed0" / "round1"
    run_dir = tmp_path / "run"
    args = [f"task={TASK}", "algo=ddpgbc", "experiment=smoke", "demos=interventions", f"demos.path={dataset}",
            "demos.frames=intervention", "experiment.epochs=1", "algo.offline_steps=2", f"run_dir={run_dir}",
            "tensorboard=false", "progress=false"]
    main(args)
    config = json.loads((run_dir / "config.json").read_text())
    segments, eps = load_demos(DemoSpec(path=str(dataset), num=1000, successful_only=False, frames="intervention"))
    assert config["demos"]["frames"] == "intervention" and config["demo_episodes"] == eps
    assert len(segments) >= 1
    # The frame selection is part of the run's configuration: the same overrides resume, another is refused.
    main([*args, "resume=true"])
    assert json.loads((run_dir / "metrics.jsonl").read_text().splitlines()[-1])["epoch"] == 1
    with pytest.raises(SystemExit):
        main([*[a for a in args if not a.startswith("demos.frames")], "demos.frames=human", "resume=true"])
    assert "another configuration" in capsys.readouterr().err


def test_exports_carry_who_acted_and_the_policy_proposal(experiment, tmp_path, monkeypatch):
    """robomimic HDF5 and Minari round trips of an intervention session, read back by h5py and minari themselves;
    a dataset of whole demos exports without the columns."""
    h5py = pytest.importorskip("h5py", reason="robomimic export needs h5py")
    minari = pytest.importorskip("minari", reason="Minari export needs minari")
    from surrol_data.datasets.export_minari import export_minari
    from surrol_data.datasets.export_robomimic import export_robomimic

    out, _, _ = experiment
    session, demos = out / "work" / TASK / "seed0" / "round1", out / "work" / TASK / "seed0" / "demos"
    trajs = DatasetReader(session).trajectories()
    assert any(t.flags[INTERVENTION].any() for t in trajs)

    path = export_robomimic(session, tmp_path / "hil.hdf5", progress=False)
    with h5py.File(path, "r") as f:
        for i, traj in enumerate(trajs):
            demo = f[f"data/demo_{i}"]
            assert np.array_equal(demo["is_intervention"][()], traj.flags[INTERVENTION].any(axis=1).astype(np.float32))
            assert np.array_equal(demo["intervention_arms"][()].astype(bool), traj.flags[INTERVENTION])
            assert np.array_equal(demo["policy_actions"][()], traj.policy_action)
            assert np.array_equal(demo["actions"][()], traj.action)
    with h5py.File(export_robomimic(demos, tmp_path / "demos.hdf5", progress=False), "r") as f:
        assert "is_intervention" not in f["data/demo_0"] and "policy_actions" not in f["data/demo_0"]

    export_minari(session, tmp_path / "minari", dataset_id="surrol/NeedleReach/hil-v0", progress=False)
    export_minari(demos, tmp_path / "minari", dataset_id="surrol/NeedleReach/demos-v0", progress=False)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    for episode, traj in zip(minari.load_dataset("surrol/NeedleReach/hil-v0").iterate_episodes(), trajs, strict=True):
        assert np.array_equal(episode.infos["is_intervention"][1:], traj.flags[INTERVENTION].any(axis=1))
        assert not episode.infos["is_intervention"][0]
        assert np.array_equal(episode.infos["policy_action"][1:], traj.policy_action)
    plain = next(minari.load_dataset("surrol/NeedleReach/demos-v0").iterate_episodes())
    assert "is_intervention" not in plain.infos and "policy_action" not in plain.infos

"""Intervention sessions: a policy acts, an operator takes over with a takeover control, the dataset says who acted.

Real components throughout: the PyBullet tasks, the simulated operator as a supervisor, the real ``lerobot`` dataset
writer and ``LeRobotDataset`` reader, BC checkpoints loaded through ``load_policy``.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from surrol_data.algos.bc import BCConfig, BCPolicy
from surrol_data.algos.networks import DeterministicActor
from surrol_data.algos.normalizer import Normalizer
from surrol_data.algos.policies import describe_policy, load_policy
from surrol_data.cli import app
from surrol_data.collect.devices import BUTTON_TAKEOVER, Device, DeviceFrame
from surrol_data.collect.devices.trace import mapping_from_dict, read_trace, trace_path
from surrol_data.collect.haptic_source import collect_haptic
from surrol_data.collect.mapping import ActionMapper, view_to_action
from surrol_data.collect.operator.supervisor import PATIENCE_S
from surrol_data.datasets.interventions import intervention_counts
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.schema import IS_INTERVENTION, POLICY_ACTION
from surrol_data.envs import env_id

REACH = "NeedleReach"     # 7-D observation, 3-D goal, no object: a supervised episode takes seconds


def constant_policy(path: Path, action, obs_dim: int, goal_dim: int = 3) -> Path:
    """A BC checkpoint (the format ``load_policy`` reads) whose action is always ``action``: zero weights, the last
    layer's bias at atanh(action)."""
    actor = DeterministicActor(obs_dim, goal_dim, len(action), (8,))
    with torch.no_grad():
        for weight in actor.parameters():
            weight.zero_()
        last = [m for m in actor.net.modules() if isinstance(m, torch.nn.Linear)][-1]
        last.bias.copy_(torch.atanh(torch.tensor(action, dtype=torch.float32).clamp(-0.999, 0.999)))
    return BCPolicy(actor, Normalizer(obs_dim), Normalizer(goal_dim), BCConfig(hidden_sizes=(8,))).save(path)


def _invoke(args: list[str]):
    result = CliRunner().invoke(app, args)
    return result, " ".join(result.output.split())


@pytest.fixture(scope="module")
def reach_session(tmp_path_factory):
    """Two operators (an expert, then a novice appended) supervising a policy that never moves, on NeedleReach."""
    tmp = tmp_path_factory.mktemp("intervene")
    policy = constant_policy(tmp / "still.pt", [0, 0, 0, 0, 0], obs_dim=7)
    out = tmp / "ds"
    outputs = []
    for extra in (["--skill", "expert", "--operator-id", "e1", "--num-episodes", "2"],
                  ["--skill", "novice", "--operator-id", "n1", "--num-episodes", "1", "--append"]):
        result, text = _invoke(["collect", "--source", "intervene", "--policy", str(policy), "--device", "operator",
                                "--task", REACH, "--out", str(out), *extra])
        assert result.exit_code == 0, result.output
        outputs.append(text)
    return out, policy, outputs


def test_the_supervisor_takes_over_a_still_policy_and_every_episode_succeeds(reach_session):
    out, _, outputs = reach_session
    assert "took over" in outputs[0]
    reader = DatasetReader(out)
    rows = reader.episodes
    assert list(rows["source"]) == ["intervention"] * 3 and rows["success"].all()
    assert list(rows["operator_id"]) == ["e1", "e1", "n1"] and rows["operator_simulated"].all()
    for ep in range(3):
        counts = intervention_counts(reader.trajectory(ep).flags["intervention"])
        # The person waits PATIENCE_S for progress, then reacts: never before, and within a few reaction times.
        assert counts.takeovers >= 1 and PATIENCE_S <= counts.time_to_takeover_s <= PATIENCE_S + 1.5
        assert 0 < counts.intervention_frames < counts.frames


def test_is_intervention_is_true_exactly_on_the_takeover_frames(reach_session):
    """The flag against an independent record (the device trace's takeover button), and the executed action against
    the policy's proposal where the policy acted and the operator's mapped hand where the operator did."""
    out, _, _ = reach_session
    reader = DatasetReader(out)
    for ep in range(len(reader)):
        traj = reader.trajectory(ep)
        trace = read_trace(trace_path(out, ep))
        buttons = trace.frames[0][:, 6].astype(int)
        takeover = (buttons & BUTTON_TAKEOVER) > 0
        np.testing.assert_array_equal(traj.flags["intervention"][:, 0], takeover)
        policy_frames = ~takeover
        np.testing.assert_array_equal(traj.action[policy_frames], traj.policy_action[policy_frames])
        np.testing.assert_array_equal(traj.policy_action, np.zeros_like(traj.policy_action))   # the still policy
        # The mapping of the recorded hand (in the frame of the task's fixed endoscope); at a takeover the jaw
        # command goes on from the one last executed.
        mapper = ActionMapper(mapping_from_dict(trace.meta["mapping"][0]))
        env = gym.make(env_id(REACH))
        env.reset(seed=int(reader.episodes.loc[ep, "seed"]))
        view = view_to_action(env, 0)
        env.close()
        operator, last_jaw = [], mapper.jaw
        for t, row in enumerate(trace.frames[0]):
            if takeover[t] and (t == 0 or not takeover[t - 1]):
                mapper.jaw = float(last_jaw)
            operator.append(mapper(DeviceFrame.from_row(row), view).arm)
            last_jaw = traj.action[t, 4]
        operator = np.array(operator)
        np.testing.assert_allclose(traj.action[takeover], operator[takeover], atol=1e-6)
        assert np.abs(traj.action[takeover][:, :3]).max() > 0.05      # the operator really moved the tool


def test_lerobot_dataset_reads_the_flag_as_hil_serl_writes_it(reach_session):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out, _, _ = reach_session
    reader = DatasetReader(out)
    ds = LeRobotDataset("local/intervene", root=out, video_backend="pyav")
    assert ds.meta.features[IS_INTERVENTION]["dtype"] == "float32"
    assert tuple(ds.meta.features[IS_INTERVENTION]["shape"]) == (1,)
    flags = np.concatenate([reader.trajectory(ep).flags["intervention"][:, 0] for ep in range(len(reader))])
    read = np.array([float(ds[i][IS_INTERVENTION].item()) for i in range(len(ds))])
    np.testing.assert_array_equal(read, flags.astype(np.float32))
    assert tuple(ds[0][POLICY_ACTION].shape) == (5,)


def test_provenance_names_the_policy_the_operator_and_the_counts(reach_session):
    out, policy, _ = reach_session
    reader = DatasetReader(out)
    row = reader.episodes.iloc[0]
    assert (row["device"], row["skill"], row["operator_id"]) == ("simulated-operator", "expert", "e1")
    settings = json.loads(row["device_settings"])
    assert settings["policy"]["sha256"] == hashlib.sha256(policy.read_bytes()).hexdigest()
    assert settings["policy"]["path"] == str(policy.resolve()) and settings["policy"]["algorithm"] == "surrol_data.bc/1"
    counts = intervention_counts(reader.trajectory(0).flags["intervention"])
    assert settings["intervention"]["takeovers"] == counts.takeovers
    assert settings["intervention"]["intervention_frames"] == counts.intervention_frames
    assert settings["supervisor_events"][0][1] == "takeover:no-progress"
    assert json.loads(row["operator_params"])["supervisor"]["patience_s"] == PATIENCE_S
    from surrol_data.datasets.validate import validate_dataset

    assert validate_dataset(out) == []


def test_info_and_assess_report_takeovers_per_operator(reach_session, tmp_path):
    from surrol_data.datasets.info import render_info_text, summarize
    from surrol_data.evaluation.assess import assess_dataset, assessment_markdown

    out, _, _ = reach_session
    reader = DatasetReader(out)
    per_episode = [intervention_counts(reader.trajectory(ep).flags["intervention"]) for ep in range(3)]
    groups = {g["operator_id"]: g for g in summarize(out)["interventions"]}
    assert set(groups) == {"e1", "n1"}
    assert groups["e1"]["takeovers"] == per_episode[0].takeovers + per_episode[1].takeovers
    assert groups["n1"]["takeovers"] == per_episode[2].takeovers and groups["n1"]["episodes"] == 1
    assert "Interventions by operator" in render_info_text(out)

    result = assess_dataset(out)
    operators = {r["group"]: r for r in result.operators.to_dict("records")}
    assert operators["n1 (intervention)"]["takeovers"] == per_episode[2].takeovers
    assert "Takeovers / ep" in assessment_markdown(result)
    cli, text = _invoke(["assess", str(out)])
    assert cli.exit_code == 0 and "Takeovers" in text


def test_describe_policy_reads_the_training_run(tmp_path, reach_session):
    """A policy in a training run folder: the algorithm and its demos' provenance come from the run's config.json."""
    out, _, _ = reach_session
    run = tmp_path / "run"
    policy = constant_policy(run / "policy.pt", [0, 0, 0, 0, 0], obs_dim=7)
    (run / "config.json").write_text(json.dumps({"learner": "bc", "demos": {"path": str(out), "where": {}},
                                                 "demo_episodes": [0, 2]}))
    info = describe_policy(policy)
    assert info["algorithm"] == "bc"
    sources = {s["operator_id"]: s["episodes"] for s in info["training_data"]["demo_sources"]}
    assert sources == {"e1": 1, "n1": 1} and len(info["training_data"]["demo_set_hash"]) == 32


class _ScriptedHand(Device):
    """A device whose hand moves along +x at a steady pace and holds the takeover control on ``takeover`` steps."""

    name = "keyboard"

    def __init__(self, takeover: set[int]):
        self.takeover, self.k = takeover, 0

    def connect(self):
        pass

    def disconnect(self):
        pass

    def read(self) -> DeviceFrame:
        self.k += 1
        buttons = BUTTON_TAKEOVER if self.k - 1 in self.takeover else 0
        return DeviceFrame(np.array([0.0, 0.0, 2.0 * self.k]), np.zeros(3), buttons, 0.05 * self.k)


def test_two_arm_takeover_is_per_arm(tmp_path):
    """On a bimanual task each arm has its own takeover control: the arm taken over executes its operator's action,
    the other the policy's, and the dataset records each arm's flag."""
    policy = constant_policy(tmp_path / "p.pt", [0.3, 0, 0, 0, 1, -0.3, 0, 0, 0, 1], obs_dim=35)
    takeover = [set(range(3, 8)), set(range(6, 12))]
    devices = [_ScriptedHand(t) for t in takeover]
    out = tmp_path / "bi"
    result = collect_haptic("BiPegTransfer", 1, out, device=devices, operator_id="p1", skill="expert", max_steps=14,
                            keep_failures=True, realtime=False, progress=False, policy=load_policy(policy),
                            policy_info=describe_policy(policy))
    assert result.kept == 1
    traj = DatasetReader(out).trajectory(0)
    arms = traj.flags["intervention"]
    for arm in (0, 1):
        expected = np.isin(np.arange(14), sorted(takeover[arm]))
        np.testing.assert_array_equal(arms[:, arm], expected)
        slot = slice(5 * arm, 5 * arm + 5)
        np.testing.assert_allclose(traj.action[~expected, slot], traj.policy_action[~expected, slot], atol=1e-6)
        assert not np.allclose(traj.action[expected, slot], traj.policy_action[expected, slot])
    assert intervention_counts(arms).takeovers == 2


def test_the_supervisor_recovers_a_grasp_and_hands_back(tmp_path):
    """NeedlePick with a policy that only lifts with the jaw closed: no progress (nothing in the jaw) → the supervisor
    takes over and grasps the needle → hands back once it holds it → the lift alone does not bring the needle to the
    goal → it takes over again and finishes. The episode succeeds; the flag follows the takeovers."""
    policy = constant_policy(tmp_path / "lift.pt", [0, 0, 0.5, 0, -1], obs_dim=19)
    out = tmp_path / "pick"
    result = collect_haptic("NeedlePick", 1, out, device="operator", operator_id="e1", skill="expert", seed=0,
                            max_steps=250, keep_failures=True, progress=False, policy=load_policy(policy),
                            policy_info=describe_policy(policy))
    reader = DatasetReader(out)
    row = reader.episodes.iloc[0]
    events = [e for _, e in json.loads(row["device_settings"])["supervisor_events"]]
    assert events[0].startswith("takeover:") and events[1] == "hand-back" and events[2].startswith("takeover:")
    assert bool(row["success"]) and result.takeovers == 2
    flags = reader.trajectory(0).flags["intervention"][:, 0]
    # Trust lost after one hand-back: the operator keeps the control to the end.
    assert intervention_counts(flags).takeovers == 2 and flags[-1]


def test_the_supervisor_is_deterministic_per_seed_and_identity(tmp_path):
    policy = load_policy(constant_policy(tmp_path / "still.pt", [0, 0, 0, 0, 0], obs_dim=7))
    runs = []
    for name, operator in (("a", "e1"), ("b", "e1"), ("c", "e2")):
        collect_haptic(REACH, 1, tmp_path / name, device="operator", operator_id=operator, skill="expert", seed=3,
                       progress=False, policy=policy, policy_info={})
        runs.append(DatasetReader(tmp_path / name).trajectory(0))
    np.testing.assert_array_equal(runs[0].action, runs[1].action)
    np.testing.assert_array_equal(runs[0].flags["intervention"], runs[1].flags["intervention"])
    assert len(runs[0].action) != len(runs[2].action) or not np.array_equal(runs[0].action, runs[2].action)


def test_intervention_options_fail_clearly(tmp_path):
    still = constant_policy(tmp_path / "still.pt", [0, 0, 0, 0, 0], obs_dim=7)
    cases = [
        (["--source", "intervene", "--device", "operator", "--skill", "expert"], "needs --policy"),
        (["--source", "haptic", "--policy", str(still), "--device", "operator", "--skill", "expert"],
         "only of it"),
        (["--source", "intervene", "--policy", str(tmp_path / "missing.pt"), "--device", "operator", "--skill",
          "expert"], "--policy: policy spec"),
    ]
    for args, message in cases:
        task = [] if "--task" in args else ["--task", REACH]
        result, text = _invoke(["collect", *args, *task, "--num-episodes", "1", "--out", str(tmp_path / "x"),
                                "--operator-id", "e1"])
        assert result.exit_code == 2 and message in text and "Traceback" not in text, (args, text)
    assert not (tmp_path / "x").exists()


def test_a_journal_entry_keeps_who_acted(tmp_path):
    """A kill between checkpoints leaves the episode in the journal; the entry holds the flags and the proposal."""
    from surrol_data.datasets import journal
    from surrol_data.datasets.trajectory import TrajectoryBuilder

    obs = {"observation": np.zeros(7), "achieved_goal": np.zeros(3), "desired_goal": np.ones(3)}
    builder = TrajectoryBuilder(obs, np.zeros(3), np.zeros(1))
    for k in range(4):
        builder.add(np.full(5, k, np.float32), obs, -1.0, False, False, np.zeros(3), np.zeros(1), info=None,
                    intervention=[k in (1, 2)], policy_action=np.zeros(5))
    traj = builder.build()
    path = journal.write_entry(tmp_path, 0, traj, {"source": "intervention"})
    back, provenance = journal.read_entry(path)
    np.testing.assert_array_equal(back.flags["intervention"], traj.flags["intervention"])
    np.testing.assert_array_equal(back.policy_action, traj.policy_action)
    assert provenance == {"source": "intervention"}
    with pytest.raises(ValueError, match="at every step or at none"):
        builder.add(np.zeros(5), obs, -1.0, False, False, np.zeros(3), np.zeros(1))
        builder.build()


def test_touch_third_button_is_the_takeover_control():
    from surrol_data.collect.devices.touch import _buttons

    assert _buttons(0b001) == 1 and _buttons(0b010) == 2 and _buttons(0b100) == BUTTON_TAKEOVER
    assert _buttons(0b111) == 1 | 2 | BUTTON_TAKEOVER


def test_rerun_colours_the_path_by_who_acted(tmp_path, reach_session):
    from rerun.experimental import RrdReader

    from surrol_data.viz.rerun_log import OPERATOR_COLOUR, save_rrd

    out, _, _ = reach_session
    traj = DatasetReader(out).trajectory(0)
    rrd = save_rrd(tmp_path / "who.rrd", [("supervised", traj, {"source": "intervention"})])
    chunks = list(RrdReader(rrd).stream())
    path = next(ch.to_record_batch() for ch in chunks if ch.entity_path == "/world/supervised/arm0/path")
    colours = np.array(path.column("LineStrips3D:colors").to_pylist()[0], np.uint32)
    operator = colours == int.from_bytes(bytes([*OPERATOR_COLOUR, 255]), "big")
    np.testing.assert_array_equal(operator, traj.flags["intervention"][:, 0])
    assert any(ch.entity_path == "/plots/supervised/policy_action" for ch in chunks)


def test_gui_take_over_button_hands_the_arm_to_the_keyboard_and_back(tmp_path):
    """The GUI with a policy: holding *take over* drives the arm from the keys; the HUD says who acts; the dataset's
    flag is set exactly while the button was held (as the session saw it)."""
    from surrol_data.render.display import unavailable_reason

    if unavailable_reason() is not None:
        pytest.skip(str(unavailable_reason()))
    from direct.gui.DirectGui import DGG

    from surrol_data.gui.app import TrainingApp
    from surrol_data.gui.keys import WindowKeys

    still = constant_policy(tmp_path / "still.pt", [0, 0, 0, 0, 0], obs_dim=7)
    app = TrainingApp(out=tmp_path, offscreen=True, size=(480, 270), policy=load_policy(still),
                      policy_info=describe_policy(still))
    app.choose_task(REACH)
    app.set_session("keyboard", "novice", "k1")
    send, take = app.base.messenger.send, app.buttons["take over"]
    shown, clicks = {}, {}        # what the HUD said at each step seen; the step of each click
    # Frames and env steps are not locked together (a quiet machine draws several steps between two of this task's
    # calls), so each click happens at the first frame at or after its step, and the checks use the steps it happened.

    def hand(task):
        if app.hud.attempt == 1:
            shown.setdefault(app.hud.steps, app.hud.operator)
        if app.hud.steps >= 3 and "press" not in clicks:
            clicks["press"] = app.hud.steps
            send(DGG.B1PRESS + take.guiId, [None])
            send(WindowKeys.DOWN_EVENT, ["d"])
        elif app.hud.steps >= clicks.get("press", 1 << 30) + 6 and "release" not in clicks:
            clicks["release"] = app.hud.steps
            send(DGG.B1RELEASE + take.guiId, [None])
        elif app.hud.steps >= clicks.get("release", 1 << 30) + 3 and "save" not in clicks:
            clicks["save"] = app.hud.steps
            app.buttons["save"].commandFunc(None)       # save the attempt as it stands
        elif app.hud.attempt == 2 and app.hud.steps >= 2:
            app.buttons["exit"].commandFunc(None)
        return task.cont

    # Panda3D's task manager is one per process: a "hand" task left by an earlier test in this process
    # would press its own keys in this window
    app.base.taskMgr.remove("hand")
    app.base.taskMgr.add(hand, "hand")
    app.exit_after_session = True
    app.play()
    app.run()
    assert app.last_error is None
    press, release = clicks["press"], clicks["release"]
    # the HUD says who acts: the policy before the press, the operator while held, the policy after the release
    assert all(who is False for step, who in shown.items() if step < press)
    assert any(who is True for step, who in shown.items() if press < step <= release)
    assert all(who is False for step, who in shown.items() if step > release + 2)
    root = tmp_path / f"{REACH}_intervene"
    traj = DatasetReader(root).trajectory(0)
    flags = traj.flags["intervention"][:, 0]
    run = np.flatnonzero(flags)
    assert len(run) >= 4 and np.array_equal(run, np.arange(run[0], run[-1] + 1))   # one takeover, held throughout
    assert press <= run[0] <= press + 2 and release <= run[-1] + 1 <= release + 2
    assert np.abs(traj.action[flags, :3]).max() > 0.1 and not traj.action[~flags, :4].any()

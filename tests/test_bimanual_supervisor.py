"""The simulated supervisor on two-arm tasks: it watches each arm and takes over the one that goes wrong.

Real components: the PyBullet NeedleRegrasp and BiPegTransfer tasks, the simulated operator, the ``collect --source
intervene`` CLI, the real ``lerobot`` writer and ``LeRobotDataset`` reader, BC checkpoints through ``load_policy``.
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from test_interventions import _invoke, constant_policy

from surrol_data.algos.policies import describe_policy, load_policy
from surrol_data.collect.devices import BUTTON_TAKEOVER
from surrol_data.collect.devices.trace import read_trace, trace_path
from surrol_data.collect.haptic_source import collect_haptic
from surrol_data.collect.operator.plan_phases import EVENT_M, PlanPhases, phases_of
from surrol_data.collect.operator.supervisor import PATIENCE_S
from surrol_data.datasets.interventions import intervention_counts
from surrol_data.datasets.reader import DatasetReader
from surrol_data.datasets.schema import IS_INTERVENTION, POLICY_ACTION
from surrol_data.envs import env_id

REGRASP = "NeedleRegrasp"
# Both tools hold still with the jaws closed: PSM1 keeps the needle where the episode starts, PSM2 never reaches for
# it. Neither does its part: the supervisor has to take each arm over (and hands it back once its part is done).
STILL_CLOSED = [0, 0, 0, 0, -1, 0, 0, 0, 0, -1]


@pytest.fixture(scope="module")
def regrasp_session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bimanual")
    policy = constant_policy(tmp / "still.pt", STILL_CLOSED, obs_dim=35)
    out = tmp / "ds"
    result, text = _invoke(["collect", "--source", "intervene", "--policy", str(policy), "--device", "operator",
                            "--skill", "expert", "--operator-id", "e1", "--task", REGRASP, "--num-episodes", "1",
                            "--keep-failures", "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out, policy, text


def _env(task: str, seed: int = 0):
    env = gym.make(env_id(task))
    env.reset(seed=seed)
    return env


def test_the_plans_split_into_phases_by_who_holds_the_object():
    env = _env(REGRASP)
    try:
        phases = [(p.first, p.last, p.holds, p.then) for p in phases_of(env.unwrapped.oracle_waypoints, 0)]
    finally:
        env.close()
    T, F = True, False
    assert phases == [(0, 2, (T, F), (T, T)), (3, 3, (T, T), (F, T)), (4, 4, (F, T), (F, T))]
    env = _env("BiPegTransfer")
    try:
        task = env.unwrapped
        tracker = PlanPhases(task)
        assert [(p.first, p.holds) for p in tracker.phases] == [(0, (F, F)), (3, (F, T)), (8, (T, T)), (9, (T, F)),
                                                              (12, (F, F))]
        obs = task._get_obs()
        # PSM2's part at the start is a grasp: its distance to the block's wall beyond the tolerance, plus the event.
        assert tracker.remaining(1, obs) > EVENT_M and tracker.target(1, obs) is not None
        # A hand-over step of PSM1 (over its wall of the block, step 5) waits until PSM2 holds the block.
        psm1 = type("Hand", (), {"arm": 0})()
        assert tracker.may_start(psm1, 1) and not tracker.may_start(psm1, 5)
        assert tracker.update([False, True]) and tracker.index == 1 and tracker.may_start(psm1, 5)
        assert not tracker.update([False, True])          # the same grasps: the same phase
        assert tracker.update([False, False]) and tracker.index == 0    # dropped: back to PSM2's grasp
        tracker.index = 3                                 # PSM1 carries it ...
        assert tracker.lets_go_here(0) and not tracker.lets_go_here(1)
        assert tracker.update([False, False]) and tracker.last       # ... and lets go: the last phase
        assert tracker.target(0, obs) is None and tracker.remaining(0, obs) == 0.0   # nobody holds: no part left
    finally:
        env.close()


def test_the_supervisor_takes_each_arm_over_and_the_regrasp_succeeds(regrasp_session):
    out, _, text = regrasp_session
    assert "took over" in text
    reader = DatasetReader(out)
    row = reader.episodes.iloc[0]
    assert row["source"] == "intervention" and bool(row["success"]) and bool(row["operator_simulated"])
    traj = reader.trajectory(0)
    counts = intervention_counts(traj.flags["intervention"])
    assert traj.flags["intervention"].shape == (len(traj), 2)
    assert all(n >= 1 for n in counts.arm_takeovers) and counts.takeovers == sum(counts.arm_takeovers)
    assert PATIENCE_S <= counts.time_to_takeover_s <= PATIENCE_S + 1.5
    settings = json.loads(row["device_settings"])
    assert settings["intervention"]["arm_takeovers"] == list(counts.arm_takeovers)
    assert settings["intervention"]["arm_intervention_frames"] == list(counts.arm_intervention_frames)
    # The events name the arm; each arm's takeovers are the rising edges of its flag, at the events' times.
    period = settings["control_period_s"]
    for arm in (0, 1):
        flags = traj.flags["intervention"][:, arm]
        rises = np.flatnonzero(flags & ~np.concatenate([[False], flags[:-1]]))
        taken = [t for t, e, a in settings["supervisor_events"] if a == arm and e.startswith("takeover:")]
        np.testing.assert_array_equal(rises, np.round(np.array(taken) / period).astype(int))
    # (docs/interventions.md tells this story:) both arms are taken over for making no progress, PSM1 carries the
    # needle to the middle and PSM2 takes it; each is handed back once its part is done; PSM1 is taken again to let
    # go, and PSM2 to bring the needle to the target.
    assert [(e, a) for _, e, a in settings["supervisor_events"]] == [
        ("takeover:no-progress", 0), ("takeover:no-progress", 1), ("hand-back", 0), ("hand-back", 1),
        ("takeover:no-progress", 0), ("takeover:no-progress", 1)]
    assert json.loads(row["operator_params"])["supervisor"]["per_arm"] is True
    from surrol_data.datasets.validate import validate_dataset

    assert validate_dataset(out) == []


def test_per_arm_flags_follow_each_hands_takeover_control(regrasp_session):
    """Each arm's flag against an independent record (its device trace's takeover button); the arm the operator
    does not hold executes the policy's proposal; ``is_intervention`` (read by LeRobot) is their union."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out, _, _ = regrasp_session
    reader = DatasetReader(out)
    traj = reader.trajectory(0)
    trace = read_trace(trace_path(out, 0))
    arms = traj.flags["intervention"]
    for arm in (0, 1):
        takeover = (trace.frames[arm][:, 6].astype(int) & BUTTON_TAKEOVER) > 0
        np.testing.assert_array_equal(arms[:, arm], takeover)
        slot = slice(5 * arm, 5 * arm + 5)
        np.testing.assert_array_equal(traj.action[~takeover, slot], traj.policy_action[~takeover, slot])
        assert np.abs(traj.action[takeover, slot][:, :3]).max() > 0.05     # the operator moved that tool
    assert (arms[:, 0] != arms[:, 1]).any()           # one arm taken over while the policy kept the other
    ds = LeRobotDataset("local/bimanual", root=out, video_backend="pyav")
    read = np.array([float(ds[i][IS_INTERVENTION].item()) for i in range(len(ds))])
    np.testing.assert_array_equal(read, arms.any(axis=1).astype(np.float32))
    assert tuple(ds[0][POLICY_ACTION].shape) == (10,)


def test_info_and_assess_report_the_takeovers_per_arm(regrasp_session):
    from surrol_data.datasets.info import render_info_text, summarize
    from surrol_data.evaluation.assess import assess_dataset

    out, _, _ = regrasp_session
    counts = intervention_counts(DatasetReader(out).trajectory(0).flags["intervention"])
    (group,) = summarize(out)["interventions"]
    assert group["arm_takeovers"] == list(counts.arm_takeovers) and group["takeovers"] == counts.takeovers
    text = " ".join(render_info_text(out).split())
    assert f"{counts.takeovers} ({counts.arm_takeovers[0]} + {counts.arm_takeovers[1]})" in text
    operators = {r["group"]: r for r in assess_dataset(out).operators.to_dict("records")}
    assert operators["e1 (intervention)"]["takeovers"] == counts.takeovers
    cli, text = _invoke(["assess", str(out)])
    assert cli.exit_code == 0 and "Takeovers" in text


def test_the_two_arm_supervisor_is_deterministic_per_seed_and_identity(tmp_path, regrasp_session):
    """The same person on the same episode: the session's first frames again; another person: other frames."""
    out, policy, _ = regrasp_session
    first = DatasetReader(out).trajectory(0)
    steps = int(np.flatnonzero(first.flags["intervention"].any(axis=1))[0]) + 8
    runs = []
    for name, operator in (("same", "e1"), ("other", "e2")):
        collect_haptic(REGRASP, 1, tmp_path / name, device="operator", operator_id=operator, skill="expert", seed=0,
                       max_steps=steps, keep_failures=True, progress=False, policy=load_policy(policy),
                       policy_info=describe_policy(policy))
        runs.append(DatasetReader(tmp_path / name).trajectory(0))
    np.testing.assert_array_equal(runs[0].action, first.action[:steps])
    np.testing.assert_array_equal(runs[0].flags["intervention"], first.flags["intervention"][:steps])
    assert not np.array_equal(runs[1].action, first.action[:steps])


def test_a_tool_leaving_its_workspace_is_taken_over_alone(tmp_path):
    """BiPegTransfer with a policy that drives PSM2 out of its workspace (-y) and leaves PSM1 still: PSM2 is taken
    over for leaving the workspace, one reaction after, while PSM1 stays the policy's."""
    policy = constant_policy(tmp_path / "away.pt", [0, 0, 0, 0, 0.5, 0, -1, 0, 0, 0.5], obs_dim=35)
    out = tmp_path / "peg"
    collect_haptic("BiPegTransfer", 1, out, device="operator", operator_id="e1", skill="expert", seed=0,
                   max_steps=10, keep_failures=True, progress=False, policy=load_policy(policy),
                   policy_info=describe_policy(policy))
    reader = DatasetReader(out)
    arms = reader.trajectory(0).flags["intervention"]
    events = json.loads(reader.episodes.iloc[0]["device_settings"])["supervisor_events"]
    assert events[0][1:] == ["takeover:workspace", 1]
    assert arms[:, 1].any() and not arms[:, 0].any()


def test_a_collision_coming_is_blamed_on_the_tool_that_closed_the_gap():
    from surrol_data.collect.mapping import MappingSettings
    from surrol_data.collect.operator import SimulatedOperator
    from surrol_data.collect.operator.arm_supervisor import COLLISION_M, arm_supervisors

    env = _env("BiPegTransfer")
    try:
        hands = arm_supervisors([SimulatedOperator(env, "expert", "e1", MappingSettings(), 0, arm=a) for a in (0, 1)])
        watch = hands[0].watch
        assert watch is hands[1].watch
        before = np.array([[0.55, 0.006, 0.7], [0.55, -0.004, 0.7]])          # 10 mm apart
        watch.tips_before = before
        watch.tips = before + [[0, -0.004, 0], [0, 0.001, 0]]                 # PSM1 came 4 mm closer, PSM2 1 mm
        assert np.linalg.norm(watch.tips[0] - watch.tips[1]) < COLLISION_M
        assert hands[0]._collision_coming() and not hands[1]._collision_coming()
        watch.tips = before + [[0, -0.002, 0], [0, 0.0, 0]]                   # 8 mm apart: not yet close
        assert not hands[0]._collision_coming() and not hands[1]._collision_coming()
    finally:
        env.close()

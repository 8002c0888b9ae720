"""The simulated human operator: a device whose frames come from a person model watching the scene.

Per env step the session calls ``observe(obs, info)`` and then ``read()``. The operator works like a person
at a Touch stylus who knows the task's steps (the task's plan, ``PsmEnv.oracle_waypoints``) but not the
scene's exact numbers:

* **perceive**: the error between the tool and the current subgoal, with noise that grows with distance,
  worst along the height axis, and a per-person height misjudgement;
* **plan**: a submovement of the hand through the person's internal model of the mapping (the inverse of
  :class:`MappingSettings`, with a gain error for novices), timed by Fitts' law and the person's comfortable
  tool speed, started after a reaction delay; corrective submovements follow until the error looks small;
* **move**: the hand model of :mod:`surrol_data.collect.operator.motor` (minimum-jerk submovements, noise,
  tremor) produces the stylus pose at each read;
* **buttons**: button 1 to close the jaw on the object; button 2 (clutch) to re-centre the hand when the next
  move would run into the edge of the stylus' workspace — experts re-position before a long move, novices
  when they hit the edge;
* **slip** (:mod:`.slips`): a hurried grasp closes the jaw before the tool has settled on the grasp point; while
  carrying, the finger on the jaw button may relax for a moment (the jaw opens and the object falls);
* **recover**: when the object does not come along as the tool lifts or pulls, or falls from the jaw
  (``info["grasped"]`` is false), open, back off, re-approach the object where it now lies, and grasp again; give up
  after a few failures;
* **place**: bringing a held object to where the plan lets go of it, judge it against its seat right beside it
  (finer perception, the task's tolerance, more corrections; on a one-object task turn the object, not the tool,
  until it looks aligned); after letting go on a one-hand task, watch it settle and, when the task's success does
  not show, pick it up again where it lies and place it once more.

What the operator sees of a task comes through a view (:mod:`.views`): one PSM as it is, one arm of a bimanual
task (two operators made the hands of one person with :meth:`SimulatedOperator.work_together` share the
plan's steps), or the camera of an ECM task (its one step: null the task's ``action_error``).

The operator keeps its own clock; every random draw comes from a generator seeded by (seed, operator
identity, arm, the task's random generator as the episode's reset left it: see ``episode_key``), so the same operator
on the same episode makes the same frames, whatever the physics computes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from surrol_data.collect.devices.base import BUTTON_CLUTCH, BUTTON_JAW, Device, DeviceError, DeviceFrame
from surrol_data.collect.mapping import MappingSettings, view_to_action
from surrol_data.collect.operator.motor import MIN_JERK_PEAK_SPEED, POSE_DIM, Hand, fitts_duration
from surrol_data.collect.operator.profiles import OperatorParams, identity_seed, operator_params
from surrol_data.collect.operator.slips import Slips
from surrol_data.collect.operator.views import task_view
from surrol_data.envs.physics import JAW_OPEN_RAD
from surrol_data.envs.psm_env import wrap_angle

# The Touch stylus' usable workspace is about 160 × 120 × 70 mm (x, y, z) around its centre; its last gimbal
# (the stylus roll that drives the tool's rotation) turns about ±125°.
DEVICE_HALF_RANGE = np.array([80.0, 60.0, 35.0, 2.2])
GIMBAL_MARGIN_RAD = 0.2
# Observation layout of single-PSM tasks with an object (PsmEnv._get_obs): tip 0:3, tip yaw 5, jaw 6,
# the object's grasp point 13:16 and its yaw 18.
_TIP, _YAW, _JAW, _OBJECT_POINT, _OBJECT_YAW = slice(0, 3), 5, 6, slice(13, 16), 18
_LIFT_TO_NOTICE_MM = 2.0     # a person sees the object stay behind once the tool has moved this much (lifting it,
                             # or pulling a handle)
_CLUTCH_SPEED_MM_S = 250.0   # re-centring the hand moves nothing on screen: it goes at ordinary reaching speed
_CLUTCH_TARGET_MM = 20.0     # and needs no precision (the Fitts width of a re-centring move)
# A person grasping an object that lies on a surface takes the open jaws down onto the surface before closing
# (the jaws only hold what lies between the blades, so closing a little high grasps nothing): the grasp
# approach and the grasp aim this far below the plan's grasp point, and the surface stops the tool.
_GRASP_PRESS_MM = 1.0
# Placing a held object (a block into its groove, onto a peg) a person judges the object against its seat right
# beside it, a relative judgement far finer than an absolute one: perception noise is this fraction of the usual,
# the person aims for the task's tolerance (or half their usual accuracy, whichever is looser) and allows
# themselves this many times their usual corrections.
_PLACING_NOISE = 0.5
_PLACING_ACCURACY = 0.5
_PLACING_CORRECTIONS = 2
# After letting go the person watches the object settle this many reaction times before judging the placement.
_PLACEMENT_LOOK_REACTIONS = 2.0
_SLIPS_SALT = 41   # the episode's generator for slips (slips.py) is its own, so the movements draw as before


@dataclass
class _Subgoal:
    """One step of the operator's plan: bring the tool to ``target`` with ``yaw``, then set the jaw."""
    target: np.ndarray | Callable[[dict], np.ndarray]   # tip position, real metres (or of the observation)
    yaw: float | None
    jaw_closed: bool
    tol_mm: float
    yaw_tol: float
    final: bool = False
    anchor: np.ndarray | None = None      # object grasp point and yaw when the target was set (object-relative)
    snapshot: bool = False                # a callable target fixed where it points when the step begins
    placing: bool = False                 # brings a held object to where the next step lets go of it
    object_yaw: float | None = None       # a placing step: the held object's yaw there as the plan intends it

    def moved_with_object(self, point: np.ndarray, yaw: float) -> "_Subgoal":
        """The same subgoal for an object that has moved since (after a failed grasp pushed it)."""
        if self.anchor is None or callable(self.target):
            return self
        d_yaw = float(wrap_angle(yaw - self.anchor[3]))
        return _Subgoal(self.target + (point - self.anchor[:3]), None if self.yaw is None else self.yaw + d_yaw,
                        self.jaw_closed, self.tol_mm, self.yaw_tol, self.final, np.array([*point, yaw]),
                        self.snapshot, self.placing, self.object_yaw)


def episode_key(task) -> list[int]:
    """What tells one episode from another for the operator's noise: the task's random generator as its reset left
    it (PCG64 state and increment), i.e. the reset's seed and the draws that set the scene up.

    Not the observation: a key hashed from the first observation's float32 bits made every episode another draw of
    the person's noise whenever the physics changed in the last bits. With the reference's PSM base yaw the tool's
    first roll/pitch/yaw read −7e-17 instead of −5e-17 rad (numerical zeros), and NeedlePick's novice succeeded in 4
    of 8 episodes instead of 7 (seeds 1000–1007) on the same scenes; rounding the observation to 1 µm / 1 µrad did
    not help where the reset itself settles an arm under load (NeedleRings' first observation moved by 2e-5), so
    the key does not read the physics at all. An unseeded reset advances the generator: a new key."""
    state = task.np_random.bit_generator.state["state"]
    return [int(state["state"]), int(state["inc"])]


class Team:
    """The two hands of one person on a bimanual task: both follow the task's two-arm plan, and a hand starts
    step ``i`` only once the other has finished step ``i − 1`` (a hand-over: the receiving hand closes
    before the giving hand opens). Made by :meth:`SimulatedOperator.work_together`."""

    def __init__(self, members: list["SimulatedOperator"]):
        self.members = members

    def may_start(self, member: "SimulatedOperator", index: int) -> bool:
        return all(other._idle or other._index >= index for other in self.members if other is not member)


class SimulatedOperator(Device):
    """A simulated person operating arm ``arm`` of ``env`` (a PSM, or the ECM of a camera task) through a stylus
    (see the module docstring).

    ``skill`` is a profile of :data:`ALL_PROFILES` (``expert``, ``novice``, ``expert_matched``, ...);
    ``operator_id`` names the person (their parameters are drawn
    from it); ``mapping`` is the device mapping the session uses (the operator's internal model inverts it);
    ``seed`` makes sessions reproducible. ``overrides`` replaces model parameters (e.g. to make a person who
    misjudges height by 3 mm).
    """

    name = "simulated-operator"

    def __init__(self, env, skill: str, operator_id: str, mapping: MappingSettings, seed: int, arm: int = 0,
                 *, overrides: dict | None = None):
        task = getattr(env, "unwrapped", env)
        self.view = task_view(task, arm)
        if not isinstance(mapping, MappingSettings):
            raise TypeError(f"mapping must be a MappingSettings, got {type(mapping).__name__}")
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self.env = task
        self.mapping = mapping
        self._model_mapping = self.view.mapping(mapping)   # what the person's internal model inverts
        self._period = self.view.control_period_s
        self._max_speed_mm_s = self.view.position_unit_m * 1000.0 / self._period     # an action of 1 per step
        self._max_angle_speed = self.view.angle_unit_rad / self._period
        self._team: Team | None = None
        self._gate = None           # a supervised arm of a two-arm task: waits on the scene (see take_over)
        self.skill = skill
        self.operator_id = str(operator_id)
        self.seed = int(seed)
        self.arm = arm
        self.params: OperatorParams = operator_params(skill, self.operator_id, overrides)
        self._identity = identity_seed(self.params.skill, self.operator_id)
        self._connected = False
        self._clock = 0.0          # the device clock (s): frame timestamps, continuing across episodes
        self._episode_start = 0.0
        self._step = 0
        self._obs: dict | None = None
        self._info: dict = {}
        self._marker = None
        self._events: list[tuple[float, str]] = []

    @staticmethod
    def work_together(operators: list["SimulatedOperator"]) -> None:
        """Make ``operators`` (one per arm of a bimanual task) the hands of one person (see :class:`Team`)."""
        arms = sorted(op.arm for op in operators)
        if arms != list(range(len(operators))) or len({id(op.env) for op in operators}) != 1:
            raise ValueError(f"work_together takes one operator per arm of one env, got arms {arms}")
        team = Team(list(operators))
        for op in operators:
            op._team = team

    # ------------------------------------------------------------------ Device API
    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def settings(self) -> dict:
        return {"model": "minimum-jerk submovements (Fitts timing, reaction delay, signal-dependent noise, tremor) "
                         "following the task plan with perception noise, clutching and grasp recovery",
                "skill": self.skill, "operator_id": self.operator_id, "seed": self.seed, "arm": self.arm,
                "view": self.view.kind,
                "device_half_range": DEVICE_HALF_RANGE.tolist(), "params": self.params.as_dict()}

    @property
    def events(self) -> tuple[tuple[float, str], ...]:
        """What the operator did this episode, as (seconds since the episode began, event): ``clutch``, ``hesitate``, ``close``,
        ``open``, ``overshoot``, ``grip-lapse``, ``grasp-failed``, ``placement-failed``, ``gave-up``, ``done``."""
        return tuple(self._events)

    def observe(self, obs: dict, info: dict) -> None:
        view = self.view
        self._obs, self._info = view.observation(obs), view.info(info)
        # A reset makes a new plan (new dicts) and a new goal array: that is how a new episode shows itself.
        marker = view.episode_marker()
        if marker is not self._marker:
            self._marker = marker
            self._begin_episode(self._obs, view.plan())
            self._reset_obs, self._takeovers = self._obs, 0
            if view.holds_at_start(info):
                # The task starts with the object in this hand: button 1 is held from the first frame.
                self._jaw_closed, self._jaw_change_s = True, -np.inf

    def read(self) -> DeviceFrame:
        if not self._connected:
            raise DeviceError("the simulated operator is not connected; call connect() (or use it as a context manager)")
        if self._obs is None:
            raise DeviceError("the simulated operator has not seen the scene; call observe(obs, info) after every "
                              "env reset and step, before read()")
        # The model runs on episode time from whole steps, so an episode's frames do not depend on the clock.
        t = self._step * self._period
        self._step += 1
        self._clock = self._episode_start + self._step * self._period
        self._maybe_lapse(t)
        self._monitor_grasp(t)
        if t >= self._next_decision_s:
            self._decide(t)
        pose = self._hand.sample(t)
        buttons = 0
        if self._jaw_button_at(t) and not self._lapse_from <= t < self._lapse_until:
            buttons |= BUTTON_JAW
        if self._clutch_from <= t < self._clutch_until:
            buttons |= BUTTON_CLUTCH
        gimbal = np.zeros(3)
        gimbal[self.mapping.rotation_axis] = pose[3]
        return DeviceFrame(position_mm=pose[:3].copy(), gimbal_rad=gimbal, buttons=buttons, t=self._episode_start + t)

    # ------------------------------------------------------------------ episode set-up
    def _begin_episode(self, obs: dict, plan: list[dict], salt: tuple[int, ...] = ()) -> None:
        # (The arm too: the two hands of one person on one episode move independently.)
        key = [self.seed, self._identity, self.arm, *episode_key(self.env), *salt]
        self._rng = np.random.default_rng(np.random.SeedSequence(key))
        self._slips = Slips(self.params, np.random.default_rng(np.random.SeedSequence([*key, _SLIPS_SALT])))
        self._lapse_from = self._lapse_until = -np.inf
        p = self.params
        start = self._rng.normal(0.0, 1.0, POSE_DIM) * np.array([5.0, 5.0, 3.0, 0.05])   # where the hand rests
        self._episode_start, self._step = self._clock, 0
        self._hand = Hand(start, DEVICE_HALF_RANGE, p.motor_noise(), self._rng)
        self._plan = self._subgoals(obs, plan)
        self._index = 0
        self._corrections = 0
        self._fresh = True                 # the current subgoal has not been started yet
        self._jaw_closed = False           # what the operator is doing with button 1
        self._jaw_change_s = -np.inf       # when button 1 was last pressed or released
        self._jaw_wait_last = None         # jaw angle at the last check while waiting for the jaw
        self._holding = False              # closed on the object and waiting for it to come along
        self._hold_height = 0.0
        self._hold_tip = np.zeros(3)
        self._grasp_segment: tuple[int, int] | None = None
        self._reanchor: tuple[int, int] | None = None   # a grasp segment to aim at the object again (after a failure)
        self._failures = 0
        self._placements_failed = 0
        self._placed_at: float | None = None   # when the jaw let go of the object at its seat (the last placement)
        self._depth_bias = p.depth_bias_mm
        self._clutch_from = self._clutch_until = -np.inf
        self._idle = False
        self._last_move: tuple[np.ndarray, float] | None = None
        self._events = []
        # The first look at a new scene takes longer than a reaction.
        self._next_decision_s = 2.0 * self._reaction()

    def take_over(self, obs: dict, info: dict, hand_pose: np.ndarray, *, start: int | None = None,
                  gate=None) -> None:
        """Start driving from the scene as it is now: a person supervising a policy takes the stylus over.

        ``hand_pose`` is where the hand rests on the stylus (the device frames read so far showed it there), so the
        tool does not jump. The plan is the task's, from the step the scene calls for: holding the object, the step
        after the grasp; otherwise (re-)grasp the object where it now lies; a task without an object, its first step.
        Every draw comes from the episode's key and the number of takeovers so far: the same scene and person give
        the same takeover.

        One arm of a two-arm task (the other driven by the policy): ``start`` is the first plan step of the phase the
        scene is in (:class:`~surrol_data.collect.operator.plan_phases.PlanPhases`), and ``gate`` (an object with
        ``may_start(operator, step)``, as :class:`Team`) holds a step back until the other arm has done its part."""
        if self._team is not None:
            raise DeviceError("the simulated supervisor takes one arm over from a policy; these operators are the two "
                              "hands of one person (work_together), whose shared plan a policy's rollout does not "
                              "follow")
        if self._obs is None:
            raise DeviceError("take_over before the operator has seen the scene: call observe(obs, info) first")
        self._takeovers += 1
        view = self.view
        self._obs, self._info = view.observation(obs), view.info(info)
        self._begin_episode(self._reset_obs, view.plan(), salt=(self._takeovers,))
        self._hand = Hand(np.asarray(hand_pose, np.float64), DEVICE_HALF_RANGE, self.params.motor_noise(), self._rng)
        # The person has been watching: one reaction to the trouble seen, not a first look at a new scene.
        self._next_decision_s = self._reaction()
        self._gate = gate
        closes = [i for i, g in enumerate(self._plan) if g.jaw_closed and (i == 0 or not self._plan[i - 1].jaw_closed)]
        phase = 0 if start is None else int(start)
        self._index = min(phase, len(self._plan) - 1)
        if not (view.has_object and view.uses_jaw and closes):
            return
        state = np.asarray(self._obs["observation"], np.float64)
        holding = bool(self._info.get("grasped", False))
        # The grasp this takeover is about: the one it holds by (the last before the phase), or the one still to
        # make (the first from the phase on). A one-arm task (no phase) has its first grasp.
        if holding:
            close = max([c for c in closes if c <= phase], default=closes[0])
        else:
            close = min([c for c in closes if c >= phase], default=closes[-1])
        first, close = self._segment_ending_at(close)
        if holding:      # the policy holds it: carry on from the step after the grasp
            self._index = min(max(close + 1, phase), len(self._plan) - 1)
            self._jaw_closed, self._jaw_change_s = True, -np.inf
            self._holding, self._grasp_segment = True, (first, close)
            self._hold_height, self._hold_tip = float(state[2]), state[_TIP].copy()
            return
        if close < phase:      # this arm has no grasp left to make: it goes on with its part from the phase
            return
        point, yaw = state[_OBJECT_POINT], float(state[_OBJECT_YAW])
        self._plan[first:close + 1] = [g.moved_with_object(point, yaw) for g in self._plan[first:close + 1]]
        self._index = max(first, phase)

    def _subgoals(self, obs: dict, plan: list[dict]) -> list[_Subgoal]:
        state = np.asarray(obs["observation"], np.float64)
        has_object = self.view.has_object
        anchor = np.array([*state[_OBJECT_POINT], state[_OBJECT_YAW]]) if has_object else None
        if not plan:
            # A reach task (the achieved goal is the tip itself) needs no plan: the goal is the subgoal.
            if np.allclose(obs["achieved_goal"], state[_TIP], atol=1e-6):
                return [_Subgoal(lambda o: np.asarray(o["desired_goal"], np.float64), None, False, 2.0, np.inf,
                                 final=True)]
            raise DeviceError(f"{type(self.env).__name__} publishes no plan (oracle_waypoints is empty) and is not a "
                              "reach task: the simulated operator cannot tell what to do in it")
        goals = []
        closed = [self.view.uses_jaw and float(wp["jaw"]) < 0 for wp in plan]
        grasp_yaw = None      # the tool's yaw where the plan last closed the jaw on the object
        # The observation shows one object; where the plan grasps several (a drawer's handle, then a block; three
        # jacks) it is not the one every placing step places, and its yaw says nothing about the seat.
        one_object = sum(closed[i] and (i == 0 or not closed[i - 1]) for i in range(len(plan))) == 1
        for i, wp in enumerate(plan):
            if closed[i] and (i == 0 or not closed[i - 1]):
                grasp_yaw = wp.get("yaw")
            placing = has_object and 0 < i < len(plan) - 1 and closed[i - 1] and closed[i] and not closed[i + 1]
            target = wp["target"]
            fixed = not callable(target)
            closes_here = float(wp["jaw"]) < 0 and (i == 0 or float(plan[i - 1]["jaw"]) >= 0)
            approaches = i + 1 < len(plan) and float(wp["jaw"]) >= 0 and float(plan[i + 1]["jaw"]) < 0
            if fixed and has_object and self.view.uses_jaw and (closes_here or approaches):
                target = np.asarray(target, np.float64) - [0.0, 0.0, _GRASP_PRESS_MM / 1000.0]
            goals.append(_Subgoal(
                target=np.asarray(target, np.float64).copy() if fixed else target,
                yaw=None if not self.view.controls_angle or "yaw" not in wp else float(wp["yaw"]),
                jaw_closed=self.view.uses_jaw and float(wp["jaw"]) < 0,
                tol_mm=1000.0 * float(wp.get("tol", 1e-3)),
                yaw_tol=float(wp.get("yaw_tol", 0.05)),
                final=i == len(plan) - 1,
                anchor=anchor.copy() if fixed and anchor is not None else None,
                snapshot=bool(wp.get("snapshot", False)),
                placing=placing,
                object_yaw=(float(wrap_angle(anchor[3] + float(wp["yaw"]) - float(grasp_yaw)))
                            if placing and one_object and self.view.controls_angle and not self.view.pitch
                            and "yaw" in wp and grasp_yaw is not None and anchor is not None else None)))
        return goals

    # ------------------------------------------------------------------ perceiving
    def _reaction(self) -> float:
        p = self.params
        return p.reaction_time_s * max(0.4, 1.0 + p.reaction_jitter * self._rng.normal())

    def _perceived_error(self, goal: _Subgoal, t: float) -> tuple[np.ndarray, float]:
        """(tool position error in mm, yaw error in rad) as the operator sees it, less the motion the hand is
        still making (a person predicts where the current movement will take the tool)."""
        p = self.params
        state = np.asarray(self._obs["observation"], np.float64)
        target = goal.target(self._obs) if callable(goal.target) else goal.target
        err = (np.asarray(target, np.float64) - state[_TIP]) * 1000.0
        spread = np.array([p.lateral_noise_mm, p.lateral_noise_mm, p.depth_noise_mm]) + p.weber_fraction * np.linalg.norm(err)
        careful = _PLACING_NOISE if goal.placing else 1.0
        seen = err + self._rng.normal(0.0, 1.0, 3) * spread * careful
        seen[2] += self._depth_bias    # targets look higher than they are: the tool is stopped short
        # The scene shows the hand's motion up to the previous frame; the rest is still to come.
        pending = self._hand.remaining(t - self._period)
        seen -= self._believed_tool_motion(pending)
        if goal.yaw is None:
            return seen, 0.0
        # Placing a held object the person turns it until it looks aligned with its seat: the object's own yaw,
        # whatever angle the jaws happened to take it at.
        yaw_err = (goal.object_yaw - state[_OBJECT_YAW] if goal.object_yaw is not None and self._holding
                   else goal.yaw - state[_YAW])
        yaw_seen = float(wrap_angle(yaw_err)) + p.yaw_noise_rad * careful * self._rng.normal()
        m = self._model_mapping
        return seen, yaw_seen - pending[3] * m.rotation_scale * m.rotation_sign * self.view.angle_ratio * self.params.internal_gain

    # ------------------------------------------------------------------ the internal model of the mapping
    def _felt_rotation(self) -> np.ndarray:
        a = np.deg2rad(self.params.frame_rotation_deg)
        return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])

    def _hand_motion_for(self, tool_mm: np.ndarray, yaw: float) -> np.ndarray:
        """The hand motion the person believes moves the tool by ``tool_mm`` and turns it by ``yaw``."""
        m, gain = self._model_mapping, self.params.internal_gain
        hand = np.zeros(POSE_DIM)
        hand[:3] = m.device_delta_mm(self._felt_rotation() @ tool_mm, self._view()) / gain
        hand[3] = yaw / (m.rotation_scale * m.rotation_sign * self.view.angle_ratio) / gain
        return hand

    def _believed_tool_motion(self, hand: np.ndarray) -> np.ndarray:
        m = self._model_mapping
        return self._felt_rotation().T @ (m.tool_delta_mm(hand[:3], self._view()) * m.motion_scale
                                          * self.params.internal_gain)

    def _view(self) -> np.ndarray | None:
        """The mapping's view matrix now (camera frame): the person sees the screen, so knows how the image turns."""
        return view_to_action(self.env, self.arm) if self._model_mapping.frame == "camera" else None

    # ------------------------------------------------------------------ deciding
    def _decide(self, t: float) -> None:
        """Look at the scene and choose the next action; sets when to look again."""
        self._next_decision_s = t + self._period
        if self._reanchor is not None:
            self._aim_at_object_again()
        while not self._idle:
            waits_on = self._team or self._gate
            if waits_on is not None and not waits_on.may_start(self, self._index):
                return     # the other hand has not finished the previous step yet: wait for it
            goal = self._plan[self._index]
            if goal.snapshot and callable(goal.target):
                goal.target = np.asarray(goal.target(self._obs), np.float64).copy()
            if goal.final and self._info.get("is_success", 0.0):
                self._finish(t, "done")
                return
            if self._placement_failed(t):
                self._retry_placement(t)
                continue
            jaw = self._jaw_progress(t)
            if jaw == "moving":
                return
            if jaw == "settled":       # the jaw did what this subgoal asked: on to the next one
                self._advance()
                continue
            err, yaw_err = self._perceived_error(goal, t)
            accuracy_mm, accuracy_rad, max_corrections = self._aim(goal)
            good_enough = np.linalg.norm(err) < accuracy_mm and abs(yaw_err) < accuracy_rad
            if not goal.final and (self._corrections >= max_corrections or self._stalled(t)):
                good_enough = True   # the tool will not get closer (a contact, or the limit of the hand): accept
            if not good_enough or goal.final:
                # (The plan's last step ends only when the scene shows success: keep correcting until then.)
                self._move(t, goal, err, yaw_err)
                return
            if goal.jaw_closed != self._jaw_closed:
                # Let the tool come to rest before using the jaw (a hurried grasp does not: slips.py).
                if self._hand.busy_until() > t and not (goal.jaw_closed and self._hurried(self._index - 1)):
                    self._next_decision_s = self._hand.busy_until() + 0.5 * self._period
                    return
                if goal.jaw_closed and self._prepare_hand_for_next(t):
                    return
                self._set_jaw(t, goal.jaw_closed)
                return
            self._advance()

    def _aim(self, goal: _Subgoal) -> tuple[float, float, int]:
        """When the person is satisfied with a step: (position error mm, angle error rad, corrections allowed)."""
        p = self.params
        if self._hurried(self._index):
            # A hurried grasp: the approach looks good enough sooner, after one correction at most (slips.py).
            slack = p.early_close_slack
            return slack * max(goal.tol_mm, p.accuracy_mm), slack * max(goal.yaw_tol, p.yaw_accuracy_rad), 1
        if goal.placing:
            return (max(goal.tol_mm, _PLACING_ACCURACY * p.accuracy_mm),
                    max(goal.yaw_tol, _PLACING_ACCURACY * p.yaw_accuracy_rad), _PLACING_CORRECTIONS * p.max_corrections)
        return max(goal.tol_mm, p.accuracy_mm), max(goal.yaw_tol, p.yaw_accuracy_rad), p.max_corrections

    def _aim_at_object_again(self) -> None:
        """After a failed grasp or a drop: the grasp's steps follow the object to where it lies now."""
        start, close = self._reanchor
        self._reanchor = None
        state = np.asarray(self._obs["observation"], np.float64)
        point, yaw = state[_OBJECT_POINT], float(state[_OBJECT_YAW])
        # Indices stay those of the task's plan (the other hand of a bimanual task keeps to them too).
        self._plan[start:close + 1] = [g.moved_with_object(point, yaw) for g in self._plan[start:close + 1]]

    def _alone_at_grasp(self, index: int) -> bool:
        """Step ``index`` approaches a grasp (the next step closes the jaw) that this hand makes alone."""
        plan = self._plan
        if not (0 <= index < len(plan) - 1 and plan[index + 1].jaw_closed and not plan[index].jaw_closed):
            return False
        # Only a grasp made alone slips: a hand taking an object over from the other hand (two hands of one person,
        # or an arm beside a policy's) waits on it. (BiPegTransfer's expert, hurried at the hand-over as well,
        # succeeded in 6 of 10 episodes instead of 9.)
        return self._team is None and self._gate is None

    def _attempt_key(self, index: int) -> tuple:
        return (index, self._failures, self._takeovers)

    def _hurried(self, index: int) -> bool:
        """Step ``index`` approaches a grasp made alone and this attempt at it is hurried."""
        return self._alone_at_grasp(index) and self._slips.hurried(self._attempt_key(index))

    def _maybe_lapse(self, t: float) -> None:
        """While carrying a held object (the hand moving it), the grip on the jaw button may lapse (slips.py)."""
        if t < self._lapse_until:
            return
        if self._lapse_until > -np.inf:
            # The lapse is over: the finger presses again, unless the person saw the object fall meanwhile.
            self._lapse_from = self._lapse_until = -np.inf
            if not self._info.get("grasped", True):
                self._jaw_closed, self._jaw_change_s = False, -np.inf
            return
        if not (self._holding and self._jaw_closed and not self._idle):
            return
        if self._hand.busy_until() <= t or self._info.get("is_success", 0.0):
            return
        # Only where the plan places nothing (NeedlePick: lift and carry): a peg or block that falls lands
        # on its side, which this operator cannot pick up again, so on the placing tasks a lapse ended the episode
        # (PegBoard's novice succeeded in 2 of 10 episodes instead of 10).
        if any(g.placing for g in self._plan):
            return
        duration = self._slips.lapse(self._period)
        if duration > 0.0:
            self._lapse_from, self._lapse_until = t, t + duration
            self._events.append((t, "grip-lapse"))

    def _advance(self) -> None:
        self._index += 1
        self._corrections = 0
        self._fresh = True
        self._last_move = None

    def _stalled(self, t: float) -> bool:
        """The last movement hardly moved the tool (it rests on something): pushing on will not help."""
        if self._last_move is None or self._hand.busy_until() > t:
            return False
        tip_then, planned_mm = self._last_move
        moved_mm = 1000.0 * np.linalg.norm(np.asarray(self._obs["observation"][_TIP], np.float64) - tip_then)
        return planned_mm > 0.5 and moved_mm < 0.3 * planned_mm

    def _finish(self, t: float, event: str) -> None:
        self._idle = True
        self._events.append((t, event))
        self._next_decision_s = np.inf

    def _hesitation(self, t: float) -> float:
        p = self.params
        if self._rng.random() >= p.hesitation_probability:
            return 0.0
        self._events.append((t, "hesitate"))
        return float(self._rng.gamma(3.0, p.hesitation_mean_s / 3.0))

    def _jaw_progress(self, t: float) -> str | None:
        """After pressing or releasing button 1, watch the jaw until it stops moving: ``moving``, then
        ``settled`` once (None when not waiting for the jaw)."""
        if self._jaw_wait_last is None:
            return None
        angle = float(self._obs["observation"][_JAW])
        # Settled: fully there, or stopped (closed on an object).
        there = angle < 0.1 * JAW_OPEN_RAD if self._jaw_closed else angle > 0.9 * JAW_OPEN_RAD
        settled = there or abs(angle - self._jaw_wait_last) < 0.02
        self._jaw_wait_last = angle
        if not settled:
            self._next_decision_s = t + self._period
            return "moving"
        self._jaw_wait_last = None
        if self._jaw_closed:
            self._holding = True
            self._hold_height = float(self._obs["observation"][2])
            self._hold_tip = np.asarray(self._obs["observation"][_TIP], np.float64).copy()
            self._grasp_segment = self._segment_ending_at(self._index)
        elif self._is_last_placement(self._index - 1):
            self._placed_at = t
        return "settled"

    def _is_last_placement(self, index: int) -> bool:
        """Step ``index`` places the object that completes the task (one person checks it; no later placing step).
        Two hands of one person hand over rather than place: theirs is not checked."""
        return (self._team is None and self._gate is None and self._grasp_segment is not None and 0 <= index and self._plan[index].placing
                and not any(g.placing for g in self._plan[index + 1:]))

    def _segment_ending_at(self, close_index: int) -> tuple[int, int]:
        """The subgoals that lead to the grasp at ``close_index``: the open approach before it, and it."""
        start = close_index
        while start > 0 and not self._plan[start - 1].jaw_closed:
            start -= 1
        return start, close_index

    # ------------------------------------------------------------------ acting
    def _hesitation_once(self, t: float, goal: _Subgoal) -> float:
        """A person may pause before starting a delicate step (a fine approach, a grasp, a retry) — once."""
        if not self._fresh:
            return 0.0
        self._fresh = False
        delicate = goal.tol_mm < 1.0 or goal.jaw_closed
        return self._hesitation(t) if delicate else 0.0

    def _set_jaw(self, t: float, closed: bool) -> None:
        delay = self._reaction() + self._hesitation_once(t, self._plan[self._index])
        self._jaw_closed = closed
        self._jaw_change_s = t + delay
        self._jaw_wait_last = float(self._obs["observation"][_JAW])
        self._events.append((t + delay, "close" if closed else "open"))
        if not closed:
            self._holding = False
        self._next_decision_s = t + delay + self.params.jaw_wait_s

    def _jaw_button_at(self, t: float) -> bool:
        return self._jaw_closed == (t >= self._jaw_change_s)

    def _room(self) -> np.ndarray:
        """How far from the centre the person lets the hand go before clutching."""
        margin = 0.0 if self._jaw_closed else self.params.clutch_margin_mm
        return DEVICE_HALF_RANGE - np.array([margin, margin, margin, GIMBAL_MARGIN_RAD])

    def _prepare_hand_for_next(self, t: float) -> bool:
        """An expert about to grasp re-positions the hand first if the carry would run into the workspace edge
        (with the jaw button held a clutch press would switch to camera mode). True when it clutched."""
        if not self.params.anticipates_clutch or self._index + 1 >= len(self._plan):
            return False
        err, yaw_err = self._perceived_error(self._plan[self._index + 1], t)
        hand = self._hand_motion_for(err, yaw_err)
        now, room = self._hand.planned_pose(), DEVICE_HALF_RANGE - np.array([2.0, 2.0, 2.0, GIMBAL_MARGIN_RAD])
        if np.all(np.abs(now + hand) <= room):
            return False
        home = self._clutch_home(now, hand, room, reactive=False)
        if home is None:
            return False
        self._clutch(t + self._reaction(), now, home)
        return True

    def _move(self, t: float, goal: _Subgoal, err_mm: np.ndarray, yaw_err: float) -> None:
        p = self.params
        delay = self._reaction() + self._hesitation_once(t, goal)
        # The orientation looks right: only the position is corrected. Where the angle is the goal itself (an
        # ECM roll), the person keeps turning until the scene shows success.
        tol, accuracy, _ = self._aim(goal)
        if goal.final and self.view.angle_is_goal:
            accuracy = goal.yaw_tol
        if abs(yaw_err) < accuracy:
            yaw_err = 0.0
        if self._corrections == 0 and self._alone_at_grasp(self._index):
            # The first movement down to a grasp may go deeper than meant (slips.py): seen, and corrected, next look.
            deeper = self._slips.overshoot_mm(self._attempt_key(self._index))
            if deeper > 0.0:
                err_mm = err_mm - [0.0, 0.0, deeper]
                self._events.append((t, "overshoot"))
        hand = self._hand_motion_for(err_mm, yaw_err)
        now, room = self._hand.planned_pose(), self._room()
        end = now + hand
        if np.any(np.abs(end) > room):
            # Holding the jaw button, a clutch press is camera mode: clutch then only when truly blocked.
            home = self._clutch_home(now, hand, room, reactive=self._jaw_closed)
            if home is not None:
                self._clutch(t + delay, now, home)
                return
            hand = np.clip(end, -room, room) - now
        tool_mm = float(np.linalg.norm(self._believed_tool_motion(hand)))
        duration = max(fitts_duration(tool_mm + 10.0 * abs(yaw_err), 2.0 * tol, p.fitts_intercept_s,
                                      p.fitts_slope_s_per_bit),
                       MIN_JERK_PEAK_SPEED * tool_mm / (p.speed_fraction * self._max_speed_mm_s),
                       MIN_JERK_PEAK_SPEED * abs(yaw_err) / (p.speed_fraction * self._max_angle_speed))
        sub = self._hand.move(t + delay, hand, duration)
        self._corrections += 1
        self._last_move = (np.asarray(self._obs["observation"][_TIP], np.float64).copy(), tool_mm)
        # Corrections overlap the movement they correct: look again about one reaction time before it ends.
        self._next_decision_s = max(sub.end_s - p.reaction_time_s, t + delay + 0.5 * duration)

    def _clutch_home(self, now: np.ndarray, hand: np.ndarray, room: np.ndarray,
                     reactive: bool) -> np.ndarray | None:
        """Where to put the hand with the clutch held before this move, or None to move (truncated) as is."""
        p = self.params
        over = np.abs(now + hand) > room
        if p.anticipates_clutch and not reactive:
            # Centre the coming move in the workspace; do it only if that really gains room.
            home = np.clip(-hand / 2.0, -room, room)
            gained = np.abs(np.clip(home + hand, -room, room) - home) - np.abs(np.clip(now + hand, -room, room) - now)
            worth = over & (gained > np.array([5.0, 5.0, 5.0, 0.2]))
            return np.where(worth, home, now) if worth.any() else None
        # Otherwise the edge is noticed only when the hand is (almost) there; then every axis that would
        # overrun is re-centred. A hand that has most of its room still ahead moves first (truncated): a move
        # longer than three times the room would otherwise be clutched for again and again from the centre.
        left = room - np.sign(hand) * now          # room still ahead in the direction of the move
        blocked = over & (left < 0.3 * np.abs(hand)) & (left < 0.6 * room)
        if not blocked.any():
            return None
        home = np.where(over, self._rng.normal(0.0, 1.0, POSE_DIM) * np.array([6.0, 6.0, 4.0, 0.1]), now)
        return np.clip(home, -room, room)

    def _clutch(self, start: float, now: np.ndarray, home: np.ndarray) -> None:
        """Hold button 2, carry the hand to ``home``, release: the tool stays where it is meanwhile."""
        distance = float(np.linalg.norm(home[:3] - now[:3]))
        duration = max(fitts_duration(distance, _CLUTCH_TARGET_MM, self.params.fitts_intercept_s,
                                      self.params.fitts_slope_s_per_bit),
                       MIN_JERK_PEAK_SPEED * distance / _CLUTCH_SPEED_MM_S, 0.3)
        move_at = start + 0.1    # press first, then move
        sub = self._hand.move(move_at, home - now, duration)
        self._clutch_from = start
        # Frames read before end + one period still contain hand motion; they must be clutched too.
        self._clutch_until = sub.end_s + self._period - 1e-9
        self._events.append((start, "clutch"))
        self._next_decision_s = self._clutch_until + 1e-9

    # ------------------------------------------------------------------ failed placements
    def _placement_failed(self, t: float) -> bool:
        """The person let the object go at its seat and sees it did not go in (the task's success does not show)
        once they have watched it settle."""
        if self._placed_at is None or self._info.get("is_success", 0.0):
            return False
        return t - self._placed_at >= _PLACEMENT_LOOK_REACTIONS * self.params.reaction_time_s

    def _retry_placement(self, t: float) -> None:
        """Pick the object up again where it now lies and place it once more (or give up)."""
        self._placements_failed += 1
        self._placed_at = None
        self._events.append((t, "placement-failed"))
        if self._placements_failed >= self.params.max_grasp_attempts:
            self._finish(t, "gave-up")
            return
        state = np.asarray(self._obs["observation"], np.float64)
        point, yaw = state[_OBJECT_POINT], float(state[_OBJECT_YAW])
        start, close = self._grasp_segment
        release = next(i for i in range(close, len(self._plan)) if self._plan[i].placing) + 1
        self._plan[start:release] = [g.moved_with_object(point, yaw) for g in self._plan[start:release]]
        self._index = start
        self._corrections = 0
        self._fresh = True
        self._last_move = None
        self._next_decision_s = t + self._reaction() + self._hesitation(t)

    # ------------------------------------------------------------------ failed grasps
    def _monitor_grasp(self, t: float) -> None:
        """While holding, watch the object: if it stays behind as the tool moves on (lifts it, pulls it), the grasp
        failed."""
        if not self._holding or self._idle or self._info.get("grasped", True):
            return
        moved_mm = np.linalg.norm(np.asarray(self._obs["observation"][_TIP], np.float64) - self._hold_tip) * 1000.0
        if moved_mm < _LIFT_TO_NOTICE_MM:
            return
        self._recover(t)

    def _recover(self, t: float) -> None:
        """Open, back off, re-approach the object where it lies now, grasp again (or give up)."""
        p = self.params
        self._failures += 1
        self._events.append((t, "grasp-failed"))
        delay = self._reaction()
        self._hand.halt(t + delay)
        self._holding = False
        # (A button already released, in or after a lapse of the grip, stays released.)
        pressed = self._jaw_button_at(t) and not self._lapse_from <= t < self._lapse_until
        self._jaw_change_s = t + delay if pressed else -np.inf
        self._jaw_closed = False
        self._lapse_from = self._lapse_until = -np.inf
        self._jaw_wait_last = None
        self._events.append((t + delay, "open"))
        if self._failures >= p.max_grasp_attempts:
            self._finish(t + delay, "gave-up")
            return
        # The failure showed the person their height misjudgement: most of it is corrected for the retry.
        self._depth_bias *= p.depth_learning
        state = np.asarray(self._obs["observation"], np.float64)
        start, close = self._grasp_segment
        # The grasp is aimed again at the object where it lies once the person looks again, after backing off: an
        # object that fell from the jaw is still falling when the person sees it go.
        self._reanchor = (start, close)
        self._index = start
        self._corrections = 0
        self._fresh = True
        self._last_move = None
        # Back off in one quick move (no aiming needed) to about backoff_mm above where the grasp closed,
        # collect oneself, then re-approach.
        risen_mm = (float(state[2]) - self._hold_height) * 1000.0
        up_mm = max(p.backoff_mm - risen_mm, 0.0)
        up = self._hand_motion_for(np.array([0.0, 0.0, up_mm]), 0.0)
        up = np.clip(self._hand.planned_pose() + up, -DEVICE_HALF_RANGE, DEVICE_HALF_RANGE) - self._hand.planned_pose()
        duration = max(MIN_JERK_PEAK_SPEED * up_mm / (p.speed_fraction * self._max_speed_mm_s), 0.2)
        sub = self._hand.move(t + delay + 0.1, up, duration)
        self._next_decision_s = sub.end_s + self._hesitation(sub.end_s)

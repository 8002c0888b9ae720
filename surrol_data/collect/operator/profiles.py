"""Skill profiles of the simulated operator and the between-operator variety within a profile.

A profile (``expert``, ``novice``) holds population-typical values of every parameter of the operator model;
an operator identity (a string id) draws its own values around them from a seed derived from the id, so
``novice/alice`` is the same person in every session and differs from ``novice/bob``.

Values are in the hand's units where they concern the hand (mm at the stylus, gimbal rad), in tool units
(mm at the tool tip, tool rad) where they concern what the operator sees. Typical magnitudes follow the motor
control literature: simple reaction times 0.2–0.45 s, Fitts slopes 0.1–0.25 s/bit, physiological tremor
8–12 Hz at a tenth of a millimetre; experts move faster, perceive depth better and anticipate the clutch.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass

import numpy as np

from surrol_data.collect.operator.motor import MotorNoise


@dataclass(frozen=True)
class OperatorParams:
    skill: str
    # timing
    reaction_time_s: float          # perceive → start moving (or press a button)
    reaction_jitter: float          # sd of the reaction time, as a fraction of it
    fitts_intercept_s: float        # Fitts' law a
    fitts_slope_s_per_bit: float    # Fitts' law b
    speed_fraction: float           # peak tool speed the operator is comfortable with, fraction of the tool's limit
    # motor noise (hand units)
    endpoint_sd: float              # submovement endpoint scatter per unit amplitude
    drift_sd: float                 # drift per unit of distance travelled
    tremor_mm: float
    tremor_hz: float
    tremor_gimbal_rad: float
    # perception (tool units)
    lateral_noise_mm: float         # sd of a perceived position error across the view
    depth_noise_mm: float           # sd along the height axis, which a monitor view shows worst
    weber_fraction: float           # perceived distances also err in proportion to their size
    yaw_noise_rad: float
    depth_bias_mm: float            # systematic height misjudgement (> 0: thinks targets are higher than they are)
    depth_bias_spread_mm: float     # between-operator sd of that bias
    depth_learning: float           # fraction of the bias left after a failed grasp showed it
    internal_gain: float            # the operator's belief of the motion scale, relative to the true one
    internal_gain_spread: float     # between-operator sd of that belief
    frame_rotation_deg: float       # the person's felt device axes are turned about the vertical by this much
    frame_rotation_spread_deg: float  # between-operator sd of that misalignment
    # strategy
    accuracy_mm: float              # satisfied when the perceived error is below this (or the task's tolerance)
    yaw_accuracy_rad: float
    max_corrections: int            # corrective submovements before accepting a position as good enough
    hesitation_probability: float   # chance of a pause before a delicate phase (descend, close, lift, retry)
    hesitation_mean_s: float
    clutch_margin_mm: float         # stop this far from the workspace edge and clutch
    anticipates_clutch: bool        # re-position the hand before a long move (vs. only when the edge is hit)
    jaw_wait_s: float               # time watching the jaw close before lifting
    backoff_mm: float               # retreat after a failed grasp
    max_grasp_attempts: int         # give up after this many failed grasps
    # slips (collect/operator/slips.py); drawn apart from the rest, so adding them changed no one's other values
    early_close_probability: float = 0.0   # chance that a grasp attempt is hurried: the jaw closed while settling
    early_close_slack: float = 1.0         # ... once the tool looks within this many times the usual accuracy
    grip_lapse_per_s: float = 0.0          # hazard of the finger relaxing on the jaw button while carrying
    grip_lapse_s: float = 0.5              # mean length of such a lapse
    overshoot_probability: float = 0.0     # chance that the first movement down to a grasp goes too deep
    overshoot_mm: float = 0.0              # ... by this much on average

    def motor_noise(self) -> MotorNoise:
        return MotorNoise(endpoint_sd=self.endpoint_sd, drift_sd=self.drift_sd, tremor_mm=self.tremor_mm,
                          tremor_hz=self.tremor_hz, tremor_gimbal_rad=self.tremor_gimbal_rad)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


# The error parameters (depth_bias_mm, the slips) are calibrated so that the novice/expert ratios of failed grasps,
# drops, time, path and idle time lie within the ranges published for people on robotic simulators and in the dry
# lab (benchmarks/operator_profiles.py; docs/teleoperation.md#errors-beside-peoples). The expert's grip lapses more
# per second of carrying than the novice's: experts hold with a lighter, just-sufficient grip (novices squeeze
# harder than needed), and carry the needle for a shorter time, so the novice still drops it ~2.6× as often.
PROFILES: dict[str, OperatorParams] = {
    "expert": OperatorParams(
        skill="expert", reaction_time_s=0.25, reaction_jitter=0.15, fitts_intercept_s=0.2, fitts_slope_s_per_bit=0.12,
        speed_fraction=0.85, endpoint_sd=0.06, drift_sd=0.02, tremor_mm=0.08, tremor_hz=10.0, tremor_gimbal_rad=0.002,
        lateral_noise_mm=0.2, depth_noise_mm=0.3, weber_fraction=0.03, yaw_noise_rad=0.03,
        depth_bias_mm=0.8, depth_bias_spread_mm=0.2, depth_learning=0.3, internal_gain=1.0, internal_gain_spread=0.03,
        frame_rotation_deg=0.0, frame_rotation_spread_deg=5.0,
        accuracy_mm=0.6, yaw_accuracy_rad=0.08, max_corrections=3, hesitation_probability=0.1, hesitation_mean_s=0.3,
        clutch_margin_mm=8.0, anticipates_clutch=True, jaw_wait_s=0.5, backoff_mm=6.0, max_grasp_attempts=4,
        early_close_probability=0.3, early_close_slack=3.0, grip_lapse_per_s=0.1, grip_lapse_s=0.5,
        overshoot_probability=0.1, overshoot_mm=2.0),
    "novice": OperatorParams(
        skill="novice", reaction_time_s=0.35, reaction_jitter=0.25, fitts_intercept_s=0.35, fitts_slope_s_per_bit=0.2,
        speed_fraction=0.72, endpoint_sd=0.12, drift_sd=0.06, tremor_mm=0.2, tremor_hz=9.0, tremor_gimbal_rad=0.006,
        lateral_noise_mm=0.5, depth_noise_mm=0.8, weber_fraction=0.08, yaw_noise_rad=0.08,
        depth_bias_mm=1.3, depth_bias_spread_mm=0.5, depth_learning=0.5, internal_gain=1.0, internal_gain_spread=0.15,
        frame_rotation_deg=0.0, frame_rotation_spread_deg=10.0,
        accuracy_mm=1.0, yaw_accuracy_rad=0.15, max_corrections=4, hesitation_probability=0.4, hesitation_mean_s=0.6,
        clutch_margin_mm=4.0, anticipates_clutch=False, jaw_wait_s=0.8, backoff_mm=10.0, max_grasp_attempts=4,
        early_close_probability=0.3, early_close_slack=4.0, grip_lapse_per_s=0.053, grip_lapse_s=0.6,
        overshoot_probability=0.35, overshoot_mm=3.5),
}

# Matched profiles: the paper's demo sources were matched "for fairness" — mean completion 113 steps (expert) and
# 117 (non-expert), mean tool-tip path 12.1 and 12.5 cm, on 100 NeedlePick episodes each. Our natural expert is
# faster (≈ 75 steps) and our natural novice wanders further (≈ 20 cm), so a comparison on them would measure demo
# length, not skill. The matched profiles are the same people working at the paper's pace: the expert slower and
# more deliberate (comfortable speed, Fitts intercept, a longer look at the closing jaw, using the whole workspace
# before re-centring the hand), the novice with a path near the paper novices' (a
# better-aligned felt frame and gain, less endpoint scatter, perception noise and tremor, the expert's accuracy
# reached with more corrections, a shorter back-off, a slower pace). A novice's path grows with every failed grasp
# (the back-off and re-approach), so within the paper's novice path the novice can fail about a quarter of a grasp
# per demo. Skill still shows where the paper's non-experts differed: tremor, hesitation (idle), the height
# misjudgement behind failed grasps and recoveries, reactive clutching, reaction and Fitts timing, and the slips
# (slips.py): asked to take its time, the matched expert waits on everything but the jaw, and closes it while the tool
# is still settling on half its grasps (at its own pace, a third); the matched novice does so on four in five and
# accepts a looser approach, and misjudges depth half as much again, so fails two to three times as many attempts;
# both lapse less per second than at their own pace (the slow, deliberate carry of the matched pace would otherwise
# multiply the expert's drops), the novice still 3× the expert. Calibrated with ``benchmarks/demo_sources.py`` (100
# episodes per source, 4 operators × 25).
MATCHED_PROFILES: dict[str, OperatorParams] = {
    "expert_matched": dataclasses.replace(
        PROFILES["expert"], speed_fraction=0.34, fitts_intercept_s=0.3, jaw_wait_s=1.0, frame_rotation_spread_deg=2.0,
        clutch_margin_mm=3.0, early_close_probability=0.5, early_close_slack=4.0, grip_lapse_per_s=0.012),
    "novice_matched": dataclasses.replace(
        PROFILES["novice"], frame_rotation_spread_deg=1.0, internal_gain_spread=0.02, endpoint_sd=0.05, drift_sd=0.03,
        weber_fraction=0.03, lateral_noise_mm=0.2, depth_noise_mm=0.4, accuracy_mm=0.6, max_corrections=6,
        speed_fraction=0.47, depth_bias_mm=1.2, tremor_mm=0.12, backoff_mm=3.0, early_close_probability=0.8,
        early_close_slack=5.0, grip_lapse_per_s=0.035),
}
ALL_PROFILES: dict[str, OperatorParams] = {**PROFILES, **MATCHED_PROFILES}

# Between-operator spread of the positive continuous parameters: each is multiplied by exp(N(0, IDENTITY_SPREAD)).
IDENTITY_SPREAD = 0.15
_SLIPS = ("early_close_probability", "early_close_slack", "grip_lapse_per_s", "grip_lapse_s")
# Drawn after the slips above, from the same generator: adding them changed no one's earlier slips.
_LATER_SLIPS = ("overshoot_probability", "overshoot_mm")
_SLIP_SALT = 41
_FIXED = {*_SLIPS, *_LATER_SLIPS, "skill", "anticipates_clutch", "max_corrections", "max_grasp_attempts", "depth_bias_mm",
          "depth_bias_spread_mm", "internal_gain", "internal_gain_spread", "tremor_hz", "frame_rotation_deg",
          "frame_rotation_spread_deg"}


def identity_seed(skill: str, operator_id: str) -> int:
    """A stable seed for an operator identity (the same in every process and session)."""
    return zlib.crc32(f"{skill}/{operator_id}".encode())


def operator_params(skill: str, operator_id: str, overrides: dict | None = None) -> OperatorParams:
    """The parameters of operator ``operator_id`` of profile ``skill`` (a key of :data:`ALL_PROFILES`: ``expert``,
    ``novice``, or a matched profile such as ``expert_matched``); ``overrides`` replace drawn values.

    A matched profile draws the person from the same identity seed as its skill's natural profile: ``expert/ann``
    and ``expert_matched/ann`` are one person at two paces."""
    if skill not in ALL_PROFILES:
        raise ValueError(f"unknown operator skill {skill!r}; choose one of {sorted(ALL_PROFILES)}")
    if not str(operator_id):
        raise ValueError("operator_id must be a non-empty string (it seeds the operator's identity)")
    base = ALL_PROFILES[skill]
    rng = np.random.default_rng(identity_seed(base.skill, str(operator_id)))
    drawn = {}
    for f in dataclasses.fields(OperatorParams):
        if f.name in _FIXED:
            continue
        drawn[f.name] = float(getattr(base, f.name) * np.exp(rng.normal(0.0, IDENTITY_SPREAD)))
    drawn["speed_fraction"] = min(drawn["speed_fraction"], 0.95)
    drawn["depth_learning"] = min(drawn["depth_learning"], 1.0)
    drawn["tremor_hz"] = float(np.clip(base.tremor_hz + rng.normal(0.0, 0.8), 8.0, 12.0))
    drawn["depth_bias_mm"] = float(base.depth_bias_mm + rng.normal(0.0, base.depth_bias_spread_mm))
    drawn["frame_rotation_deg"] = float(base.frame_rotation_deg + rng.normal(0.0, base.frame_rotation_spread_deg))
    drawn["internal_gain"] = float(max(base.internal_gain + rng.normal(0.0, base.internal_gain_spread), 0.5))
    # The slips come from a generator of their own: the other values of a person are those drawn before slips existed.
    slips = np.random.default_rng([identity_seed(base.skill, str(operator_id)), _SLIP_SALT])
    for name in (*_SLIPS, *_LATER_SLIPS):
        drawn[name] = float(getattr(base, name) * np.exp(slips.normal(0.0, IDENTITY_SPREAD)))
    drawn["early_close_probability"] = min(drawn["early_close_probability"], 1.0)
    drawn["overshoot_probability"] = min(drawn["overshoot_probability"], 1.0)
    params = dataclasses.replace(base, **drawn)
    if overrides:
        known = {f.name for f in dataclasses.fields(OperatorParams)} - {"skill"}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown operator parameter(s) {unknown}; known: {sorted(known)}")
        params = dataclasses.replace(params, **overrides)
    return params

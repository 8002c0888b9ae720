"""Proficiency metrics of one trajectory — the one ruler for human demos, scripted demos and policy rollouts.

They live in :mod:`surrol_data.datasets.metrics`: the dataset format stores each episode's metrics with it
(``schema``, ``validate`` and ``info`` compute them), so they sit in the datasets layer, below evaluation
(``docs/architecture.md``). This module names the same objects for the code that still imports them from here
(the batched learner); new code imports :mod:`surrol_data.datasets.metrics`.
"""

from __future__ import annotations

from surrol_data.datasets.metrics import (
    IDLE_MIN_S,
    IDLE_SPEED_M_S,
    SPARC_AMPLITUDE_THRESHOLD,
    SPARC_MAX_FREQUENCY_HZ,
    SPARC_PAD_LEVEL,
    DeviceTrace,
    Estimate,
    Proficiency,
    angular_economy_rad,
    bootstrap_ci,
    drops,
    estimate,
    failed_grasps,
    first_grasp_failed,
    idle_fraction,
    idle_time_s,
    jaw_closures,
    log_dimensionless_jerk,
    path_length_m,
    path_length_per_arm_m,
    proficiency,
    psm_tip_angles,
    rising_edges,
    sparc,
    steps_to_success,
    summarize,
    trajectory_proficiency,
)

__all__ = [
    "IDLE_MIN_S", "IDLE_SPEED_M_S", "SPARC_AMPLITUDE_THRESHOLD", "SPARC_MAX_FREQUENCY_HZ", "SPARC_PAD_LEVEL",
    "DeviceTrace", "Estimate", "Proficiency", "angular_economy_rad", "bootstrap_ci", "drops", "estimate",
    "failed_grasps", "first_grasp_failed", "idle_fraction", "idle_time_s", "jaw_closures", "log_dimensionless_jerk",
    "path_length_m", "path_length_per_arm_m", "proficiency", "psm_tip_angles", "rising_edges", "sparc",
    "steps_to_success", "summarize", "trajectory_proficiency",
]

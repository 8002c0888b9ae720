"""One evaluation episode as one row: what ``eval_episodes.csv`` and the report's evaluation files hold per episode.

The proficiency metrics a report pools (success at the last step and at any step, steps to success — −1 if
never —, path, jaw closures, failed grasps, drops, idle time) and the attempt measure's counts and outcome
(:mod:`surrol_data.datasets.attempts`; absent where the task has no grasp record or grasp point).
"""

from __future__ import annotations

from surrol_data.datasets.attempts import trajectory_attempts
from surrol_data.datasets.metrics import Proficiency, trajectory_proficiency


def episode_row(traj, proficiency: Proficiency | None = None) -> dict:
    """The row of one episode (a :class:`~surrol_data.datasets.trajectory.Trajectory`); ``proficiency`` when the
    caller has scored it already."""
    p = proficiency if proficiency is not None else trajectory_proficiency(traj)
    attempts = trajectory_attempts(traj)
    return {"final_success": p.final_success, "success": p.success, "steps_to_success": p.steps_to_success,
            "path_length_cm": p.path_length_cm, "jaw_closures": p.jaw_closures, "failed_grasps": p.failed_grasps,
            "drops": p.drops, "idle_time_s": p.idle_time_s, **(attempts.as_row() if attempts is not None else {})}

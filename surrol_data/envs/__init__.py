"""Surgical tasks as Gymnasium goal-conditioned envs. Importing this package registers ``SurRoL/<Task>-v0``.

Registration is cheap: PyBullet is imported only when an env is made.
"""

from gymnasium.envs.registration import register, registry

TASKS = {
    "NeedleReach": "surrol_data.envs.tasks.needle_reach:NeedleReach",
    "GauzeRetrieve": "surrol_data.envs.tasks.gauze_retrieve:GauzeRetrieve",
    "NeedlePick": "surrol_data.envs.tasks.needle_pick:NeedlePick",
    "PegTransfer": "surrol_data.envs.tasks.peg_transfer:PegTransfer",
    "NeedleRegrasp": "surrol_data.envs.tasks.needle_regrasp:NeedleRegrasp",
    "BiPegTransfer": "surrol_data.envs.tasks.bi_peg_transfer:BiPegTransfer",
    "ECMReach": "surrol_data.envs.tasks.ecm_reach:ECMReach",
    "MisOrient": "surrol_data.envs.tasks.mis_orient:MisOrient",
    "StaticTrack": "surrol_data.envs.tasks.static_track:StaticTrack",
    "ActiveTrack": "surrol_data.envs.tasks.active_track:ActiveTrack",
    "PickAndPlace": "surrol_data.envs.tasks.pick_and_place:PickAndPlace",
    "MatchBoard": "surrol_data.envs.tasks.match_board:MatchBoard",
    "MatchBoardPanel": "surrol_data.envs.tasks.match_board_panel:MatchBoardPanel",
    "PegBoard": "surrol_data.envs.tasks.peg_board:PegBoard",
    "NeedleRings": "surrol_data.envs.tasks.needle_rings:NeedleRings",
}
# 50 steps (the reference's horizon) unless a task needs longer, sized for people: ActiveTrack follows its target
# for 500 steps; haptic collection allows 3x the registered horizon, and simulated novices take 406 ± 65 steps on
# PickAndPlace (two jacks), 362 ± 68 on MatchBoardPanel (drawer, then block) and 183 ± 22 on MatchBoard
# (benchmarks/operator_tasks.py; the oracle: 50, 59 and 35); PegBoard takes the ring off, turns it and threads
# it, NeedleRings turns the needle through in steps and hands it off (their oracles need ~40 and ~60 steps).
LONG_HORIZONS = {"ActiveTrack": 500, "PickAndPlace": 200, "MatchBoard": 100, "MatchBoardPanel": 200,
                 "PegBoard": 100, "NeedleRings": 100}
DEFAULT_MAX_EPISODE_STEPS = {name: LONG_HORIZONS.get(name, 50) for name in TASKS}


def env_id(task: str) -> str:
    """``NeedlePick`` → ``SurRoL/NeedlePick-v0`` (full ids pass through)."""
    if task.startswith("SurRoL/"):
        return task
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}")
    return f"SurRoL/{task}-v0"


for _name, _entry in TASKS.items():
    if env_id(_name) not in registry:
        register(id=env_id(_name), entry_point=_entry, max_episode_steps=DEFAULT_MAX_EPISODE_STEPS[_name])

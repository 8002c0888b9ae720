"""Surgical tasks as Gymnasium goal-conditioned envs. Importing this package registers ``SurRoL/<Task>-v0``.

Registration is cheap: PyBullet is imported only when an env is made.
"""

from gymnasium.envs.registration import register, registry

TASKS = {
    "NeedleReach": "surrol_data.envs.tasks.needle_reach:NeedleReach",
    "NeedlePick": "surrol_data.envs.tasks.needle_pick:NeedlePick",
}
DEFAULT_MAX_EPISODE_STEPS = {name: 50 for name in TASKS}


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

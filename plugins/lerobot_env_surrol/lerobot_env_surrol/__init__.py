"""LeRobot's plugin hook for the SurRoL tasks: importing this registers ``--env.type=surrol``.

LeRobot's scripts (``lerobot-eval``, ``lerobot-train``) import each installed distribution named ``lerobot_env_*``
before they parse their arguments; the env config itself lives in :mod:`surrol_data.evaluation.lerobot_env`.
"""

from surrol_data.evaluation.lerobot_env import SurrolEnv

__all__ = ["SurrolEnv"]

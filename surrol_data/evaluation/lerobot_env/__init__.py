"""The SurRoL tasks as a LeRobot env, so ``lerobot-eval`` (and ``lerobot-train``'s periodic eval) can run them.

LeRobot 0.6 finds third-party envs through its config registry (``EnvConfig.register_subclass``); importing
this module registers ``--env.type=surrol``. LeRobot's scripts import every installed distribution named
``lerobot_env_*`` first: the ``lerobot_env_surrol`` plugin (``plugins/lerobot_env_surrol``, installed in a clone by
``uv sync``/``uv run``) imports this module, so no other flag is needed (elsewhere,
``--env.discover_packages_path=surrol_data.evaluation.lerobot_env`` does the same; lerobot's parser wants a package
there, hence this module is one)::

    lerobot-eval --env.type=surrol --env.task=NeedlePick --policy.path=OUT/checkpoints/last/pretrained_model \\
        --eval.n_episodes=10 --eval.batch_size=1

:class:`LerobotObservation` gives each env's observation the names lerobot's ``preprocess_observation`` maps
onto the dataset keys the policy was trained on: ``agent_pos`` → ``observation.state``,
``environment_state`` (achieved goal then desired goal, as in :mod:`surrol_data.datasets.schema`) →
``observation.environment_state`` and, with ``--env.camera_width/height``, ``pixels/endoscope`` →
``observation.images.endoscope`` (what ``collect --camera`` records); without them, a policy given by
``--policy.path`` that reads the endoscope image brings its own image size. Success is the env's
``info["is_success"]``, which lerobot-eval reads.
The proficiency metrics are ``surrol-data eval --policy lerobot:DIR``'s (same env, same seeds policy).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

from surrol_data.datasets.schema import FPS
from surrol_data.datasets.trajectory import ENV_CAMERA


class LerobotObservation(gym.ObservationWrapper):
    """``{observation, achieved_goal, desired_goal}`` → ``{agent_pos, environment_state}`` (lerobot's names)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        spaces = env.observation_space
        goal = spaces["desired_goal"].shape[0]
        box = lambda n: gym.spaces.Box(-np.inf, np.inf, shape=(n,), dtype=np.float32)  # noqa: E731
        named = {"agent_pos": box(spaces["observation"].shape[0]), "environment_state": box(2 * goal)}
        if "image" in spaces.spaces:
            named["pixels"] = gym.spaces.Dict({ENV_CAMERA: spaces["image"]})
        self.observation_space = gym.spaces.Dict(named)
        self.task_description = env.unwrapped.TASK  # the natural-language task lerobot passes to policies
        self.task = self.task_description

    def observation(self, observation: dict) -> dict:
        named = {"agent_pos": np.asarray(observation["observation"], np.float32),
                 "environment_state": np.concatenate([observation["achieved_goal"], observation["desired_goal"]]
                                                     ).astype(np.float32)}
        if "image" in observation:
            named["pixels"] = {ENV_CAMERA: np.asarray(observation["image"], np.uint8)}
        return named


def policy_image_size(args=None) -> tuple[int, int] | None:
    """(height, width) of the endoscope image the policy of ``--policy.path`` (a local folder) reads, or None.

    LeRobot builds the env before the policy and gives the env's config no view of it; without this, a camera
    policy evaluated without ``--env.camera_width/height`` fails deep in lerobot with
    ``KeyError: 'observation.images.endoscope'``."""
    import json
    from pathlib import Path

    from lerobot.configs.parser import get_path_arg

    path = get_path_arg("policy", args)
    config = Path(path) / "config.json" if path else None
    if config is None or not config.is_file():
        return None
    feature = json.loads(config.read_text()).get("input_features", {}).get(f"{OBS_IMAGES}.{ENV_CAMERA}")
    if not feature:
        return None
    channels, height, width = feature["shape"]
    return int(height), int(width)


@EnvConfig.register_subclass("surrol")
@dataclass
class SurrolEnv(EnvConfig):
    """``--env.type=surrol --env.task=NeedlePick`` (any task of ``surrol-data tasks``)."""

    task: str | None = "NeedlePick"
    fps: int = FPS
    episode_length: int | None = None  # None: the task's registered horizon
    render_mode: str = "rgb_array"      # lerobot-eval renders videos of the first episodes
    camera_width: int = 0               # > 0: the endoscope image, for policies trained on `collect --camera` data
    camera_height: int = 0
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=lambda: {
        ACTION: ACTION, "agent_pos": OBS_STATE, "environment_state": OBS_ENV_STATE,
        f"pixels/{ENV_CAMERA}": f"{OBS_IMAGES}.{ENV_CAMERA}"})

    def __post_init__(self):
        import surrol_data.envs  # noqa: F401  (registers the SurRoL/* ids)

        size = policy_image_size()
        if self.camera_width <= 0 and self.camera_height <= 0:
            if size is not None:   # the policy reads the endoscope image: the env renders it at its size
                self.camera_height, self.camera_width = size
        elif size is not None and (self.camera_height, self.camera_width) != size:
            # lerobot would resize nothing and run the policy on images it never saw: refused, saying both sizes
            raise ValueError(f"--env.camera_width/height {self.camera_width}x{self.camera_height} differ from the "
                             f"{size[1]}x{size[0]} endoscope images the policy was trained on: leave them out (the "
                             "env then renders at the policy's size) or give the policy's")

        env = gym.make(self.gym_id)
        try:
            spaces = env.observation_space
            self.features = {
                ACTION: PolicyFeature(type=FeatureType.ACTION, shape=env.action_space.shape),
                "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=spaces["observation"].shape),
                "environment_state": PolicyFeature(type=FeatureType.ENV,
                                                   shape=(2 * spaces["desired_goal"].shape[0],)),
            }
            if self.camera_width > 0:
                self.features[f"pixels/{ENV_CAMERA}"] = PolicyFeature(
                    type=FeatureType.VISUAL, shape=(self.camera_height, self.camera_width, 3))
        finally:
            env.close()

    @property
    def package_name(self) -> str:
        return "surrol_data.envs"

    @property
    def gym_id(self) -> str:
        from surrol_data.envs import env_id

        return env_id(self.task)

    @property
    def gym_kwargs(self) -> dict:
        kwargs = {"render_mode": self.render_mode}
        if self.camera_width > 0:
            kwargs.update(camera=True, camera_size=(self.camera_width, self.camera_height))
        if self.episode_length is not None:
            kwargs["max_episode_steps"] = self.episode_length
        return kwargs

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        import surrol_data.envs  # noqa: F401

        def make_one():
            return LerobotObservation(gym.make(self.gym_id, disable_env_checker=self.disable_env_checker,
                                               **self.gym_kwargs))

        env_cls = gym.vector.AsyncVectorEnv if (use_async_envs and n_envs > 1) else gym.vector.SyncVectorEnv
        vec = env_cls([make_one for _ in range(n_envs)], autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
        return {self.type: {0: vec}}

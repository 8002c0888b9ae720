"""A policy trained by LeRobot's own code (``lerobot-train``: ACT, Diffusion, ...) as a rollout policy here.

``surrol-data eval --policy lerobot:DIR`` loads it: DIR is a ``pretrained_model`` folder (``config.json``,
``model.safetensors`` and the saved pre/post-processors), a checkpoint folder holding one, or a
``lerobot-train`` output folder (its last checkpoint is used). Nothing is downloaded: the folder must be local.

Each step the env's observation becomes the batch the policy was trained on, under the dataset's keys
(:mod:`surrol_data.datasets.schema`): ``observation.state`` is the env's ``observation``,
``observation.environment_state`` its achieved goal followed by its desired goal, and
``observation.images.endoscope`` (a policy trained on ``collect --camera`` data) the endoscope image: the env is
then made with its camera at the size the policy was trained on (:attr:`LerobotPolicy.env_kwargs`). The policy's own
preprocessor normalises it with the dataset statistics saved at training time, and its postprocessor turns
the output back into an env action. Chunking policies (ACT) keep a queue of actions, cleared at every
episode start by :meth:`LerobotPolicy.reset` (``rollout`` calls it after each ``env.reset``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from surrol_data.datasets.schema import ENV_STATE
from surrol_data.datasets.trajectory import ENV_CAMERA

PREFIX = "lerobot:"
_STATE = "observation.state"
_CAMERA = f"observation.images.{ENV_CAMERA}"


def pretrained_dir(path: str | Path) -> Path:
    """The ``pretrained_model`` folder under ``path`` (see the module doc), or FileNotFoundError saying what is
    expected."""
    path = Path(path)
    for candidate in (path, path / "pretrained_model", path / "checkpoints" / "last" / "pretrained_model"):
        if (candidate / "config.json").is_file() and (candidate / "model.safetensors").is_file():
            return candidate
    raise FileNotFoundError(f"{path} holds no LeRobot policy: expected a folder with config.json and "
                            "model.safetensors (lerobot-train's checkpoints/<step>/pretrained_model), a checkpoint "
                            "folder or a lerobot-train output folder")


class LerobotPolicy:
    """Callable ``obs_dict -> action`` around a LeRobot ``PreTrainedPolicy`` and its processors."""

    def __init__(self, path: str | Path, device: str | None = None):
        import torch
        from lerobot.configs import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        from surrol_data.datasets.lerobot_compat import check_lerobot

        check_lerobot()
        self.path = pretrained_dir(path)
        device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        config = PreTrainedConfig.from_pretrained(self.path, local_files_only=True)
        config.device = device
        unknown = sorted(set(config.input_features) - {_STATE, ENV_STATE, _CAMERA})
        if unknown:
            raise ValueError(f"{self.path} expects inputs {unknown} that a surrol_data env does not produce; "
                             f"it can use {_STATE}, {ENV_STATE} and {_CAMERA}")
        self.input_shapes = {k: tuple(ft.shape) for k, ft in config.input_features.items()}
        # gym.make arguments the policy needs: the endoscope image at the size it was trained on (C, H, W)
        self.env_kwargs: dict = {}
        if _CAMERA in config.input_features:
            _, height, width = self.input_shapes[_CAMERA]
            self.env_kwargs = {"camera": True, "camera_size": (width, height)}
        self.action_shape = tuple(config.output_features["action"].shape)
        self.policy = get_policy_class(config.type).from_pretrained(self.path, config=config, local_files_only=True)
        self.policy.eval()
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            config, pretrained_path=str(self.path),
            preprocessor_overrides={"device_processor": {"device": device}})
        self._torch = torch

    def reset(self) -> None:
        """Forget queued actions: a new episode starts."""
        self.policy.reset()

    def _batch(self, obs: dict) -> dict:
        values = {_STATE: obs["observation"], ENV_STATE: np.concatenate([obs["achieved_goal"], obs["desired_goal"]])}
        if _CAMERA in self.input_shapes:
            if "image" not in obs:
                raise ValueError(f"the policy at {self.path} sees the endoscope image: make the env with "
                                 f"{self.env_kwargs} (evaluate() does)")
            values[_CAMERA] = np.moveaxis(np.asarray(obs["image"]), -1, 0) / 255.0  # HWC uint8 -> CHW in [0, 1]
        batch = {}
        for key, shape in self.input_shapes.items():
            value = np.asarray(values[key], np.float32)
            if value.shape != shape:
                raise ValueError(f"the env gives {key} of shape {value.shape}, the policy at {self.path} was trained "
                                 f"on {shape}: evaluate it on the task its dataset was recorded on")
            batch[key] = self._torch.from_numpy(value)[None]
        return batch

    def __call__(self, obs: dict) -> np.ndarray:
        with self._torch.inference_mode():
            action = self.policy.select_action(self.preprocessor(self._batch(obs)))
            action = self.postprocessor(action)
        return action.reshape(self.action_shape).detach().cpu().numpy().astype(np.float32)


def load_lerobot_policy(spec: str) -> LerobotPolicy:
    """``"lerobot:DIR"`` -> :class:`LerobotPolicy`."""
    return LerobotPolicy(spec.removeprefix(PREFIX))

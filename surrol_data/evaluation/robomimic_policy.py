"""A policy trained by robomimic (on ``surrol-data export --format robomimic``) as a rollout policy here.

``surrol-data eval --policy robomimic:CKPT`` loads it through robomimic's own policy API
(``robomimic.utils.file_utils.policy_from_checkpoint``: the algorithm, its observation normalisation and its
``RolloutPolicy`` wrapper) and runs it in our Gymnasium env, not in robomimic's rollout code (which needs the old
``gym``). Each step the env's observation becomes robomimic's observation dict under the export's keys
(``observation``, ``achieved_goal``, ``desired_goal``; ``<camera>_image`` for a policy trained on the video: the env
is then made with its camera at the size recorded in the checkpoint's env args, :attr:`RobomimicPolicy.env_kwargs`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from surrol_data.datasets.trajectory import ENV_CAMERA

PREFIX = "robomimic:"
_IMAGE = f"{ENV_CAMERA}_image"


class RobomimicPolicy:
    """Callable ``obs_dict -> action`` around robomimic's ``RolloutPolicy``; :meth:`reset` starts an episode."""

    def __init__(self, checkpoint: str | Path):
        path = Path(checkpoint)
        if not path.is_file():
            raise FileNotFoundError(f"{path} is not a robomimic checkpoint file (robomimic's train writes "
                                    "<output_dir>/<name>/<time>/models/model_epoch_N.pth)")
        from surrol_data.extras import MissingExtra, require

        try:
            require("robomimic")
        except MissingExtra as e:
            raise ValueError(f"robomimic:CKPT: {e}") from None
        import robomimic.utils.file_utils as file_utils
        import torch

        self.path = path
        self.policy, checkpoint_dict = file_utils.policy_from_checkpoint(ckpt_path=str(path),
                                                                         device=torch.device("cpu"), verbose=False)
        self.obs_keys = list(checkpoint_dict["shape_metadata"]["all_obs_keys"])
        unknown = sorted(set(self.obs_keys) - {"observation", "achieved_goal", "desired_goal", _IMAGE})
        if unknown:
            raise ValueError(f"{path} expects observations {unknown} that a surrol_data env does not produce; it can "
                             f"use observation, achieved_goal, desired_goal and {_IMAGE}")
        env_args = checkpoint_dict.get("env_metadata") or {}
        self.env_kwargs: dict = dict(env_args.get("env_kwargs") or {}) if _IMAGE in self.obs_keys else {}
        if "camera_size" in self.env_kwargs:
            self.env_kwargs["camera_size"] = tuple(self.env_kwargs["camera_size"])
        self.policy.start_episode()

    def reset(self) -> None:
        """A new episode: robomimic's policy forgets its history (RNN state, action chunks)."""
        self.policy.start_episode()

    def __call__(self, obs: dict) -> np.ndarray:
        values = {k: np.asarray(obs[k], np.float32) for k in ("observation", "achieved_goal", "desired_goal")}
        if _IMAGE in self.obs_keys:
            if "image" not in obs:
                raise ValueError(f"the policy at {self.path} sees the endoscope image: make the env with "
                                 f"{self.env_kwargs} (evaluate() does)")
            values[_IMAGE] = np.asarray(obs["image"])   # robomimic's obs processing makes it CHW in [0, 1]
        return np.asarray(self.policy(ob={k: values[k] for k in self.obs_keys}), np.float32)


def load_robomimic_policy(spec: str) -> RobomimicPolicy:
    """``"robomimic:CKPT"`` -> :class:`RobomimicPolicy`."""
    return RobomimicPolicy(spec.removeprefix(PREFIX))

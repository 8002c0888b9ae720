"""Test helpers for the ``touch`` backend: compile ``libhd_standin.c`` and write the trajectory it serves.

``oracle_device_frames`` produces a device trajectory that completes a task: it drives the env with the
task's oracle *through the device mapping* (oracle action → the hand motion that the mapping turns into
it → the mapped action is what the env executes), so served back by the stand-in libHD, the same frames
give the same episode.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from surrol_data.collect.devices.base import BUTTON_CLUTCH, BUTTON_JAW, DeviceFrame
from surrol_data.collect.mapping import ActionMapper, MappingSettings, view_to_action
from surrol_data.envs.units import ACTION_POSITION_M, ACTION_YAW_RAD

SOURCE = Path(__file__).with_name("libhd_standin.c")


def build_libhd(out_dir: Path) -> Path:
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler (gcc) to build the stand-in libHD")
    lib = Path(out_dir) / "libHD.so"
    subprocess.run([gcc, "-shared", "-fPIC", "-O1", "-o", str(lib), str(SOURCE)], check=True, capture_output=True)
    return lib


def write_script(path: Path, frames_by_device: dict[str, list[DeviceFrame]]) -> Path:
    """The stand-in's script: ``<device> x y z g0 g1 g2 buttons`` per line, exact doubles (repr)."""
    lines = []
    for name, frames in frames_by_device.items():
        for f in frames:
            values = [*f.position_mm, *f.gimbal_rad]
            lines.append(" ".join([name, *(repr(float(v)) for v in values), str(int(f.buttons))]))
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def oracle_device_frames(task: str, seed: int, horizon: int, mapping: MappingSettings | None = None,
                         origin_mm=(0.0, 0.0, 0.0), stop_after_success: int = 2, clutch_steps=()):
    """(frames, actions, success) of the oracle's episode played through a device and the mapping."""
    mapping = mapping or MappingSettings()
    env = gym.make(f"SurRoL/{task}-v0", max_episode_steps=horizon)
    try:
        obs, _ = env.reset(seed=seed)
        mapper = ActionMapper(mapping)
        view = view_to_action(env) if mapping.frame == "camera" else None   # the endoscope is still
        pos, gimbal = np.asarray(origin_mm, np.float64), np.zeros(3)
        frames, actions, after, success = [], [], None, False
        closing = False
        for k in range(horizon):
            if k in clutch_steps:
                # clutch held: the hand re-centres (moves back) while the tool must stay put
                pos = pos - np.array([5.0, 0.0, 5.0])
                frame = DeviceFrame(pos.copy(), gimbal.copy(), BUTTON_CLUTCH, float(k))
                frames.append(frame)
                actions.append(mapper(frame, view).arm)
                obs, _, _, truncated, info = env.step(actions[-1])
                continue
            if closing and mapper.jaw > -1.0:
                # the jaw ramps closed over a few steps: hold the button and keep the hand still until it is shut
                # (the oracle's own timing assumes an instant jaw)
                a = np.array([0.0, 0.0, 0.0, 0.0, -1.0])
            else:
                a = env.unwrapped.oracle_action(obs)
            closing = a[4] < 0
            if k > 0:   # the first frame of an attempt is the reference: it cannot move the tool
                pos = pos + mapping.device_delta_mm(np.asarray(a[:3], np.float64) * ACTION_POSITION_M * 1000, view)
                gimbal = gimbal.copy()
                gimbal[mapping.rotation_axis] += float(a[3]) * ACTION_YAW_RAD / (mapping.rotation_scale
                                                                                  * mapping.rotation_sign)
            frame = DeviceFrame(pos.copy(), gimbal.copy(), BUTTON_JAW if a[4] < 0 else 0, float(k))
            frames.append(frame)
            action = mapper(frame, view).arm
            actions.append(action)
            obs, _, _, truncated, info = env.step(action)
            if info["is_success"] and after is None:
                after, success = stop_after_success, True
            elif after is not None:
                after -= 1
            if after == 0 or truncated:
                break
        return frames, np.asarray(actions, np.float32), success
    finally:
        env.close()

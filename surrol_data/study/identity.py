"""The code identity of this checkout on this machine (see :mod:`surrol_data.evaluation.code_identity`)."""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path

from surrol_data.algos.train import TrainConfig
from surrol_data.evaluation.code_identity import CodeIdentity

CODE_PATHS = ("surrol_data", "configs")
ENV_EPISODES = 3          # oracle and random episodes each, as benchmarks/env_fingerprint.py --episodes 3
RUN_SPECIFIC = ("run_dir", "seed", "demos", "resume", "overwrite", "progress", "tensorboard")


def cpu_name() -> str:
    """The processor's model name and the vector extensions that change floating-point results (FMA, AVX-512)."""
    model, flags = "unknown CPU", set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and model == "unknown CPU":
                model = value.strip()
            elif key.strip() == "flags" and not flags:
                flags = set(value.split())
    except OSError:
        import platform

        model = platform.processor() or platform.machine()
    ext = [f for f in ("fma", "avx2", "avx512f") if f in flags]
    return f"{model} [{' '.join(ext)}]" if ext else model


def repo_root() -> Path:
    return Path(__file__).resolve().parents[2]


def git_state(root: Path | None = None) -> tuple[str, bool]:
    """(commit, whether surrol_data/ or configs/ differ from it); ("unknown", True) outside a git checkout."""
    root = root or repo_root()
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                timeout=20).stdout.strip()
        status = subprocess.run(["git", "status", "--porcelain", "--", *CODE_PATHS], cwd=root, capture_output=True,
                                text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return "unknown", True
    return (commit, bool(status.strip())) if commit else ("unknown", True)


def config_fingerprint(cfg: TrainConfig) -> str:
    """Hash of the run's training config less what differs between the runs of one study (seed, demos, folder)."""
    from surrol_data.algos.train import _config_json

    shared = {k: v for k, v in _config_json(cfg).items() if k not in RUN_SPECIFIC}
    return hashlib.sha256(json.dumps(shared, sort_keys=True).encode()).hexdigest()


def current_identity(cfg: TrainConfig) -> CodeIdentity:
    """Fingerprint this checkout's env and learner for the study's task and learner config (a few seconds)."""
    from surrol_data.algos.fingerprint import learner_fingerprint
    from surrol_data.algos.train import make_env
    from surrol_data.algos.train_batched import _learner_config
    from surrol_data.envs.fingerprint import env_fingerprint

    task = cfg.env_id.split("/")[-1].rsplit("-v", 1)[0]
    env = make_env(cfg.env_id, cfg.schedule.max_episode_steps)
    try:
        space = env.observation_space
        dims = (space["observation"].shape[0], space["desired_goal"].shape[0], env.action_space.shape[0])
        learner = learner_fingerprint(_learner_config(cfg), *dims, env.unwrapped.compute_reward, cfg.schedule.her_k)
    finally:
        env.close()
    commit, dirty = git_state()
    return CodeIdentity(commit=commit, dirty=dirty, cpu=cpu_name(), env_fingerprint=env_fingerprint(task, ENV_EPISODES),
                        learner_fingerprint=learner, config_fingerprint=config_fingerprint(cfg))

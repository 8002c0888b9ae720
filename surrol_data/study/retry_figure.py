"""The paper's figure of a retry: endoscope frames of each source's policy after a failed first grasp.

The paper showed a human-trained policy grasping again after a failed first attempt where a script-trained one
stalled. Every run's report evaluation (:mod:`surrol_data.study.report_eval`) plays its kept actors on probe episodes
whose first close near the needle is made to fail (the grip disabled: :mod:`surrol_data.evaluation.grip_probe`), on
the same seeds for every run, and records what followed: the closes near it after the disabled one (its retries) and
whether the episode ended in success. The frames are chosen by that measure, the one the induced-failure table
reports, not by hand: per source, the outcome its runs' probed episodes at the epoch show most often (retried and
succeeded, retried and failed, or stalled), and the first episode (lowest seed) with it of the lowest-seed run that
has one. The episode is played again (the actor is deterministic, the seed the same; the disabled close, the retries
and the success are checked against the record) keeping PyBullet's state after every step, and the frames are drawn
afterwards from the kept states: the disabled close, the jaw reopened, the first retry, then evenly spaced to the
success (or the episode's end).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from surrol_data.evaluation.recovery_report import flags, object_name

FIGURE_FILE = "retry_frames.png"
FRAMES = 5
PROBE_OUTCOMES = ("retried_succeeded", "retried_failed", "stalled")


def probe_outcome(retries: int, final_success: bool) -> str:
    """What a probed episode did after its disabled close (the induced-failure table's categories)."""
    if retries <= 0:
        return "stalled"
    return "retried_succeeded" if final_success else "retried_failed"


@dataclass(frozen=True)
class ChosenEpisode:
    source: str
    run: Path
    seed: int           # the probe episode's env seed
    outcome: str        # its recorded probe outcome (PROBE_OUTCOMES), the source's most common one
    disabled_from: int  # the action index where its disabled close began (-1: none)
    share: str          # "k of n" probed episodes of the source's runs with that outcome


def choose_episodes(runs, epoch: int) -> list[ChosenEpisode]:
    """Per source (in the report's order), the probed episode to show (see the module docstring); sources whose runs
    hold no probed episode at ``epoch`` are left out."""
    import pandas as pd

    from surrol_data.evaluation.recovery_report import REPORT_FILE

    chosen = []
    for source in dict.fromkeys(r.source for r in runs):
        frames = []
        for run in sorted((r for r in runs if r.source == source), key=lambda r: r.seed):
            path = run.path / REPORT_FILE
            if not path.is_file():
                continue
            rows = pd.read_csv(path)
            rows = rows[(rows["epoch"] == epoch) & (rows["kind"] == "probe") & flags(rows["probed"])].copy()
            if len(rows):
                rows["outcome"] = [probe_outcome(int(r), bool(s))
                                   for r, s in zip(rows["probe_retries"], flags(rows["final_success"]))]
                frames.append((run, rows.sort_values("seed")))
        if not frames:
            continue
        counts = Counter(o for _, rows in frames for o in rows["outcome"])
        outcome, n = counts.most_common(1)[0]
        # (frames are in seed order: the first run that shows the outcome is the lowest-seed one with it)
        run, rows = next((r, x) for r, x in frames if (x["outcome"] == outcome).any())
        hit = rows[rows["outcome"] == outcome].iloc[0]
        chosen.append(ChosenEpisode(source, run.path, int(hit["seed"]), str(outcome),
                                    int(hit["probe_from"]), f"{n} of {sum(counts.values())}"))
    return chosen


def _frame_steps(traj, disabled_from: int) -> list[int]:
    """States to draw (0 = after reset, t = after action t): the disabled close, the jaw reopened after it, the first
    close after that (the retry), then evenly spaced to the first success (or the episode's end)."""
    length = len(traj.action)
    succeeded = np.flatnonzero(traj.success)
    end = int(succeeded[0]) + 1 if len(succeeded) else length
    if disabled_from < 0:
        return sorted({int(round(x)) for x in np.linspace(0, end, FRAMES)})
    closing = traj.action[:, 4] < 0
    steps = [disabled_from + 1]
    reopen = next((t for t in range(disabled_from + 1, length) if not closing[t]), None)
    if reopen is not None:
        steps.append(reopen + 1)
        retry = next((t for t in range(reopen + 1, length) if closing[t]), None)
        if retry is not None:
            steps.append(retry + 1)
    last = max(steps)
    rest = np.linspace(last, max(end, last), FRAMES - len(steps) + 1)[1:] if len(steps) < FRAMES else []
    return sorted({*steps, *(int(round(x)) for x in rest)})


def _caption(traj, step: int, disabled_from: int = -1) -> str:
    if step == 0:
        return "start"
    i = step - 1
    jaw = "closing" if traj.action[i, 4] < 0 else "open"
    if i == disabled_from:
        jaw += " (grip disabled)"
    held = bool(traj.flags["grasped"][i]) if "grasped" in traj.flags else False
    done = " · success" if bool(traj.success[: i + 1].any()) else ""
    return f"step {step} · jaw {jaw} · {'held' if held else 'not held'}{done}"


def replay_frames(env_id: str, actor: Path, seed: int, max_steps: int, size=(320, 240), renderer: str | None = None):
    """Play the probe episode ``seed`` with ``actor`` again; return (its probe record, whether it ended in success,
    [(step, caption, rgb)])."""
    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.algos.bc import BCPolicy
    from surrol_data.collect.rollout import rollout
    from surrol_data.envs.camera import make_camera
    from surrol_data.evaluation.grip_probe import InducedFailure
    from surrol_data.evaluation.rollout import policy_threads
    from surrol_data.render.display import best_renderer
    from surrol_data.render.env_view import EnvEndoscope

    probe = InducedFailure(gym.make(env_id, max_episode_steps=max_steps, render_mode="rgb_array"))
    env = _KeepStates(probe)
    try:
        policy = BCPolicy.load(actor)
        with policy_threads(policy):
            traj = rollout(env, policy, seed)
        client = env.unwrapped.client
        view = EnvEndoscope(env)
        camera = make_camera(client, tuple(size), view.scene_scale, renderer or best_renderer())
        frames = []
        for step in _frame_steps(traj, probe.record.disabled_from):
            client.restoreState(env.states[step])
            frames.append((step, _caption(traj, step, probe.record.disabled_from), camera.render(view.pose()).rgb))
        return probe.record, bool(traj.success[-1]), frames
    finally:
        env.close()


class _KeepStates(gym.Wrapper):
    """Keeps PyBullet's state after the reset and after every step (``states[t]``)."""

    def __init__(self, env):
        super().__init__(env)
        self.states: list[int] = []

    def reset(self, **kwargs):
        out = self.env.reset(**kwargs)
        self._drop()
        self.states.append(self.env.unwrapped.client.saveState())
        return out

    def step(self, action):
        out = self.env.step(action)
        self.states.append(self.env.unwrapped.client.saveState())
        return out

    def _drop(self):
        client = self.env.unwrapped.client
        for s in self.states:
            client.removeState(s)
        self.states = []

    def close(self):
        self._drop()
        self.env.close()


def write_retry_figure(runs: Sequence, out: str | Path, epoch: int,
                       renderer: str | None = None) -> tuple[Path, list[str]] | None:
    """Draw ``FIGURE_FILE`` into ``out``: a row per source (its chosen probe episode at ``epoch``, played in the
    run's env with its episode horizon), and return it with one line per row saying what was chosen and why; None
    when no run holds probed episodes at ``epoch``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from surrol_data.algos.train_batched import actor_path

    chosen = choose_episodes(runs, epoch)
    if not chosen:
        return None
    configs = {r.path: r.config for r in runs}
    rows = []
    for c in chosen:
        config = configs[c.run]
        record, success, frames = replay_frames(config["env_id"], actor_path(c.run, epoch), c.seed,
                                                int(config["schedule"]["max_episode_steps"]), renderer=renderer)
        replayed = probe_outcome(record.retries, success)
        if replayed != c.outcome or record.disabled_from != c.disabled_from:
            raise RuntimeError(f"{c.run}: probe episode {c.seed} replayed as {replayed} (disabled from action "
                               f"{record.disabled_from}), recorded as {c.outcome} (from {c.disabled_from}); the actor "
                               "or the env is not the one the run was evaluated with")
        rows.append((c, frames))
    width = max(len(f) for _, f in rows)
    fig, axes = plt.subplots(len(rows), width, figsize=(2.6 * width, 2.3 * len(rows)), squeeze=False)
    lines = []
    for r, (c, frames) in enumerate(rows):
        for k in range(width):
            ax = axes[r][k]
            ax.axis("off")
            if k < len(frames):
                step, caption, rgb = frames[k]
                ax.imshow(rgb)
                ax.set_title(caption, fontsize=7)
        label = f"{c.source}-trained\n{c.outcome.replace('_', ' ')}"
        axes[r][0].text(-0.06, 0.5, label, transform=axes[r][0].transAxes, ha="right", va="center", fontsize=9)
        lines.append(f"{c.source}-trained: `{c.outcome}` ({c.share} probed episodes of its runs at epoch {epoch}); "
                     f"shown: {c.run.parent.name}/{c.run.name}, probe seed {c.seed}")
    fig.suptitle(f"Epoch {epoch}, the first close near the {object_name(runs[0].task)} made to fail: each source's most "
                 "common outcome", fontsize=10)
    fig.tight_layout(rect=(0.08, 0, 1, 0.95))
    path = Path(out) / FIGURE_FILE
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path, lines


def retry_frames_section(runs: Sequence, out: Path, epoch: int) -> list[str]:
    """The report's section of the figure (drawn into ``out``), or none when no run has probed episodes at ``epoch``;
    a figure that cannot be drawn says why instead (the numbers above it stand without it)."""
    head = f"\n## After a failed first grasp: frames (epoch {epoch})\n"
    try:
        drawn = write_retry_figure(runs, out, epoch)
    except Exception as e:
        return [head, f"The frames could not be drawn: {type(e).__name__}: {e}\n"]
    if drawn is None:
        return []
    path, lines = drawn
    return [head, "Each source's policy on the probe episodes (the grip disabled during its first close near the "
            f"{object_name(runs[0].task)}), the episode chosen by the measure of the induced-failure table: the source's most common "
            "outcome (retried and succeeded, retried and failed, stalled), its first episode "
            "(`surrol_data/study/retry_figure.py`).\n", *(f"* {line}" for line in lines),
            f"\n![frames after a failed first grasp]({path.name})\n"]

"""The paper's figure of a retry: endoscope frames of each source's policy after a failed first grasp.

The paper showed a human-trained policy grasping again after a failed first attempt where a script-trained one
stalled. Every run's report evaluation (:mod:`surrol_data.study.report_eval`) plays its kept actors on probe episodes
whose first attempt near the grasp point is made to fail (the grip disabled), on the same seeds for every run, and
records each episode's outcome (:class:`~surrol_data.datasets.attempts.Outcome`). The frames are chosen by that
measure, not by hand: per source, the outcome its runs' probed episodes at the epoch show most often, and the first
episode (lowest seed) with it of the lowest-seed run that has one. The episode is played again (the
actor is deterministic, the seed the same; its outcome is checked against the recorded one) keeping PyBullet's state
after every step, and the frames are drawn afterwards from the kept states (drawing reads link frames with a
forward-kinematics pass, which would perturb an episode under way): the failed attempt's close, the jaw reopening,
then three evenly spaced moments to the episode's end.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

FIGURE_FILE = "retry_frames.png"
FRAMES = 5


@dataclass(frozen=True)
class ChosenEpisode:
    source: str
    run: Path
    seed: int           # the probe episode's env seed
    outcome: str        # its recorded attempt outcome, the source's most common one
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
            rows = rows[(rows["epoch"] == epoch) & (rows["kind"] == "probe") & rows["probed"].astype(bool)]
            if len(rows):
                frames.append((run, rows.sort_values("seed")))
        if not frames:
            continue
        counts = Counter(o for _, rows in frames for o in rows["attempt_outcome"])
        outcome, n = counts.most_common(1)[0]
        # (frames are in seed order: the first run that shows the outcome is the lowest-seed one with it)
        run, rows = next((r, x) for r, x in frames if (x["attempt_outcome"] == outcome).any())
        hit = rows[rows["attempt_outcome"] == outcome]
        chosen.append(ChosenEpisode(source, run.path, int(hit["seed"].iloc[0]), str(outcome),
                                    f"{n} of {sum(counts.values())}"))
    return chosen


def _frame_steps(attempts, length: int) -> list[int]:
    """States to draw (0 = after reset, t = after action t): the first attempt's close and its reopening, then evenly
    spaced to the end."""
    first = attempts.attempts[0] if attempts is not None and attempts.attempts else None
    if first is None:
        return [int(round(x)) for x in np.linspace(0, length, FRAMES)]
    close, reopen = first.start + 1, min(first.end + 1, length)
    rest = np.linspace(reopen, length, FRAMES - 1)[1:]
    return sorted({close, reopen, *(int(round(x)) for x in rest)})


def _caption(traj, step: int) -> str:
    if step == 0:
        return "start"
    i = step - 1
    jaw = "closing" if traj.action[i, 4] < 0 else "open"
    held = bool(traj.flags["grasped"][i]) if "grasped" in traj.flags else False
    done = " · success" if bool(traj.success[: i + 1].any()) else ""
    return f"step {step} · jaw {jaw} · {'held' if held else 'not held'}{done}"


def replay_frames(env_id: str, actor: Path, seed: int, max_steps: int, size=(320, 240), renderer: str | None = None):
    """Play the probe episode ``seed`` with ``actor`` again; return (its attempts, [(step, caption, rgb)])."""
    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.algos.bc import BCPolicy
    from surrol_data.collect.rollout import rollout
    from surrol_data.datasets.attempts import trajectory_attempts
    from surrol_data.envs.camera import make_camera
    from surrol_data.evaluation.grip_probe import InducedFailure
    from surrol_data.evaluation.rollout import policy_threads
    from surrol_data.render.display import best_renderer
    from surrol_data.render.env_view import EnvEndoscope

    env = _KeepStates(InducedFailure(gym.make(env_id, max_episode_steps=max_steps, render_mode="rgb_array")))
    try:
        policy = BCPolicy.load(actor)
        with policy_threads(policy):
            traj = rollout(env, policy, seed)
        attempts = trajectory_attempts(traj)
        client = env.unwrapped.client
        view = EnvEndoscope(env)
        camera = make_camera(client, tuple(size), view.scene_scale, renderer or best_renderer())
        frames = []
        for step in _frame_steps(attempts, len(traj.action)):
            client.restoreState(env.states[step])
            frames.append((step, _caption(traj, step), camera.render(view.pose()).rgb))
        return attempts, frames
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
        attempts, frames = replay_frames(config["env_id"], actor_path(c.run, epoch), c.seed,
                                         int(config["schedule"]["max_episode_steps"]), renderer=renderer)
        replayed = attempts.outcome.value if attempts is not None else "unknown"
        if replayed != c.outcome:
            raise RuntimeError(f"{c.run}: probe episode {c.seed} replayed as {replayed}, recorded as {c.outcome}; "
                               "the actor or the env is not the one the run was evaluated with")
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
    fig.suptitle(f"After a failed first grasp (grip disabled), epoch {epoch}: each source's most common outcome",
                 fontsize=10)
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
    return [head, "Each source's policy on the probe episodes (the grip disabled during its first attempt near the "
            "grasp point), the episode chosen by the measure: the source's most common outcome, its first episode "
            "(`surrol_data/study/retry_figure.py`).\n", *(f"* {line}" for line in lines),
            f"\n![frames after a failed first grasp]({path.name})\n"]

"""Many envs in few worker processes that play whole episodes on their own: the batched path's collector and evaluator.

Gymnasium's ``AsyncVectorEnv`` runs one process per env and waits for the learner's actions at every step. A
batched run steps dozens of envs (every member's episodes at once) on two cores; in lock step the envs wait
while the learner runs an update and the learner waits while the envs step, and every step costs pipe
messages and a Python round trip per member. Here each worker process holds a slice of the envs **and a copy
of the acting policy** (every member's actor weights and normaliser statistics, sent as plain arrays once per
rollout), and plays its envs' whole episodes after a single message — the exploration noise is drawn in the
parent from each member's own generator beforehand, so a worker draws no random numbers. The parent is free
between :meth:`EnvPool.rollout_async` and :meth:`EnvPool.rollout_wait` (that is where the learner's updates
run), and evaluation is one message per worker for all its episodes.

Every env is reset with an explicit seed for every episode and stepped exactly ``max_episode_steps`` times,
so no auto-reset is involved and an episode depends on its seed, policy and noise only, whichever worker ran it.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
import traceback
from dataclasses import dataclass
from functools import partial

import numpy as np

from surrol_data.algos.normalizer import standardize

INFO_KEYS = ("is_success", "tip_position", "jaw_angle", "grasped")


@dataclass
class PolicySnapshot:
    """Every member's deterministic actor π = tanh(MLP(clip((o−μ)/σ), clip((g−μ)/σ))) as plain arrays.

    ``weights[k]`` (M, in, out) and ``biases[k]`` (M, out) float32 per layer (layer k: x ↦ x·w + b);
    normaliser statistics (M, dim) float64, normalised exactly as :meth:`~surrol_data.algos.normalizer.Normalizer.normalize` does.
    """
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    obs_mean: np.ndarray
    obs_std: np.ndarray
    goal_mean: np.ndarray
    goal_std: np.ndarray
    clip: float

    def for_envs(self, member_of_env: np.ndarray) -> PolicySnapshot:
        """One row per env (the env's member's), so a worker never needs to know the member layout."""
        take = lambda xs: [x[member_of_env] for x in xs]  # noqa: E731
        return PolicySnapshot(take(self.weights), take(self.biases), self.obs_mean[member_of_env],
                              self.obs_std[member_of_env], self.goal_mean[member_of_env],
                              self.goal_std[member_of_env], self.clip)


class SnapshotActor:
    """A worker's copy of the policy: one row of weights per env, one small batched matmul per layer and step."""

    def __init__(self, snapshot: PolicySnapshot):
        import torch

        self.torch = torch
        self.s = snapshot
        self.w = [torch.from_numpy(w) for w in snapshot.weights]                  # (E, in, out)
        self.b = [torch.from_numpy(b).unsqueeze(1) for b in snapshot.biases]       # (E, 1, out)

    def __call__(self, obs: np.ndarray, goal: np.ndarray) -> np.ndarray:
        s, torch = self.s, self.torch
        o = standardize(obs, s.obs_mean, s.obs_std, s.clip)
        g = standardize(goal, s.goal_mean, s.goal_std, s.clip)
        x = torch.from_numpy(np.concatenate([o, g], -1)).unsqueeze(1)
        with torch.no_grad():
            for k, (w, b) in enumerate(zip(self.w, self.b)):
                x = torch.baddbmm(b, x, w)
                if k < len(self.w) - 1:
                    x = torch.relu(x)
            return torch.tanh(x).squeeze(1).numpy()


def explored_action(pi: np.ndarray, explore: dict | None, t: int) -> np.ndarray:
    """Step t's float32 actions (E, A) from the policy's ``pi``: as :meth:`DDPG.act` makes them, with the noise
    and random actions it would have drawn (``explore``, see :func:`_rollout`); clipped ``pi`` without."""
    if explore is None:
        return np.clip(pi, -1.0, 1.0).astype(np.float32)
    a = pi
    if explore.get("noise") is not None:
        a = np.clip(a + explore["noise"][:, t], -1.0, 1.0)
    if explore.get("replace") is not None:
        replace = explore["replace"][:, t]
        a = np.array(a, copy=True)
        a[replace] = explore["random"][replace, t]
    return np.asarray(a, np.float32)


def _rollout(envs: list, seeds: np.ndarray, snapshot: PolicySnapshot | None, explore: dict | None,
             steps: int) -> dict[str, np.ndarray]:
    """``seeds`` (R, E): R rounds of one episode in each of the E envs. ``explore`` (training): ``noise`` (E, T, A)
    added to π and clipped to [-1, 1], then ``random`` (E, T, A) where ``replace`` (E, T) is set; without it
    the deterministic policy acts (evaluation). Returns (R, E, ...) arrays: obs/ag/g (T+1 rows), action,
    reward, success, grasped (T rows; grasped where the env reports it), tip_position, jaw_angle (T+1 rows)."""
    actor = SnapshotActor(snapshot) if snapshot is not None else None
    act_dim = envs[0].action_space.shape[0]
    rounds = []
    for round_seeds in seeds:
        resets = [env.reset(seed=int(s)) for env, s in zip(envs, round_seeds)]
        obs = _stack([r[0] for r in resets])
        info = _stack_info([r[1] for r in resets])
        trace = {k: [v] for k, v in obs.items()}
        trace.update({"tip_position": [info["tip_position"]], "jaw_angle": [info["jaw_angle"]],
                      "action": [], "reward": [], "success": []})
        if "grasped" in info:
            trace["grasped"] = []
        for t in range(steps):
            a = (actor(obs["observation"], obs["desired_goal"]) if actor is not None
                 else np.zeros((len(envs), act_dim), np.float32))
            a = explored_action(a, explore, t)
            results = [env.step(ai) for env, ai in zip(envs, a)]
            obs = _stack([r[0] for r in results])
            info = _stack_info([r[4] for r in results])
            for k, v in obs.items():
                trace[k].append(v)
            trace["tip_position"].append(info["tip_position"])
            trace["jaw_angle"].append(info["jaw_angle"])
            trace["action"].append(a)
            trace["reward"].append(np.array([r[1] for r in results], np.float32))
            trace["success"].append(info["is_success"] > 0.5)
            if "grasped" in trace:
                trace["grasped"].append(np.asarray(info["grasped"]).reshape(len(envs), -1) > 0.5)
        rounds.append({k: np.stack(v, 1) for k, v in trace.items()})   # (E, T(+1), ...)
    return {k: np.stack([r[k] for r in rounds]) for k in rounds[0]}


def _stack(obs_list: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([o[k] for o in obs_list]) for k in ("observation", "achieved_goal", "desired_goal")}


def _stack_info(infos: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([np.asarray(info[k], np.float32) for info in infos]) for k in INFO_KEYS if k in infos[0]}


def _worker(conn, env_fn, n_envs: int, nice: int) -> None:
    if nice:
        os.nice(nice)   # the learner is the serial part of a cycle: let it have a core when both want one
    import torch

    torch.set_num_threads(1)
    envs = [env_fn() for _ in range(n_envs)]
    try:
        while True:
            cmd, payload = conn.recv()
            if cmd == "rollout":
                try:
                    out = _rollout(envs, *payload)
                except Exception:  # noqa: BLE001  (the parent re-raises it with the worker's traceback)
                    conn.send((None, traceback.format_exc()))
                    continue
                conn.send((out, time.process_time()))
            elif cmd == "close":
                break
    except (KeyboardInterrupt, EOFError, BrokenPipeError, ConnectionResetError):
        pass   # the parent stopped or was killed: nobody is left to send episodes to (its checkpoints are intact)
    finally:
        for env in envs:
            env.close()
        conn.close()


class EnvPool:
    """``n_envs`` copies of ``env_id`` spread over ``n_workers`` spawned processes (in-process for 0 workers).

    ``worker_nice`` lowers the workers' scheduling priority (see :func:`~surrol_data.algos.train_batched.train_batched`)."""

    def __init__(self, env_id: str, max_episode_steps: int, n_envs: int, n_workers: int = 2, worker_nice: int = 0):
        from surrol_data.algos.train import make_env

        if n_envs < 1 or n_workers < 0:
            raise ValueError(f"EnvPool needs n_envs >= 1 and n_workers >= 0, got {n_envs}, {n_workers}")
        self.n_envs, self.steps = n_envs, max_episode_steps
        env_fn = partial(make_env, env_id, max_episode_steps)
        self._local = None
        self._conns, self._procs, self._sizes = [], [], []
        self._worker_cpu: list[float] = []
        self._pending = None
        if n_workers == 0:
            self._local = [env_fn() for _ in range(n_envs)]
            self._sizes = [n_envs]
            return
        n_workers = min(n_workers, n_envs)
        sizes = [n_envs // n_workers + (w < n_envs % n_workers) for w in range(n_workers)]
        # spawn, not fork: the parent already runs torch's thread pool, which a forked child must not inherit
        ctx = mp.get_context("spawn")
        for size in sizes:
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, env_fn, size, worker_nice), daemon=True)
            proc.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(proc)
            self._sizes.append(size)
        self._worker_cpu = [0.0] * len(sizes)

    def _slices(self):
        start = 0
        for size in self._sizes:
            yield slice(start, start + size)
            start += size

    def rollout_async(self, seeds, snapshot: PolicySnapshot | None, member_of_env: np.ndarray,
                      explore: dict | None = None) -> None:
        """Start one episode per env per round (``seeds`` (R, n_envs) or (n_envs,)), acting with member
        ``member_of_env[e]``'s actor of ``snapshot`` in env e (or only ``explore``'s random actions without one)."""
        if self._pending is not None:
            raise RuntimeError("rollout_async while a rollout is still pending; call rollout_wait first")
        seeds = np.atleast_2d(np.asarray(seeds, np.int64))
        if seeds.shape[1] != self.n_envs or len(member_of_env) != self.n_envs:
            raise ValueError(f"EnvPool.rollout needs one seed and one member per env ({self.n_envs}), got seeds "
                             f"{seeds.shape} and {len(member_of_env)} members")
        member_of_env = np.asarray(member_of_env)
        parts = []
        for sl in self._slices():
            snap = snapshot.for_envs(member_of_env[sl]) if snapshot is not None else None
            exp = {k: (v[sl] if v is not None else None) for k, v in explore.items()} if explore is not None else None
            parts.append((seeds[:, sl], snap, exp, self.steps))
        if self._local is not None:
            self._pending = [_rollout(self._local, *parts[0])]
            return
        for conn, part in zip(self._conns, parts):
            conn.send(("rollout", part))
        self._pending = True

    def rollout_wait(self) -> dict[str, np.ndarray]:
        """The started rollout's (R, n_envs, ...) arrays (see :func:`_rollout`)."""
        if self._pending is None:
            raise RuntimeError("rollout_wait without a rollout_async")
        if self._local is not None:
            parts = self._pending
        else:
            parts = []
            failures = []
            for w, conn in enumerate(self._conns):
                out, cpu = conn.recv()
                if out is None:
                    failures.append(cpu)
                    continue
                parts.append(out)
                self._worker_cpu[w] = cpu
            if failures:
                self._pending = None
                raise RuntimeError(f"an env worker failed during a rollout:\n{failures[0]}")
        self._pending = None
        return {k: np.concatenate([p[k] for p in parts], 1) for k in parts[0]}

    def busy_workers(self) -> int:
        """How many workers are still playing the started rollout (0 when none is pending, or in-process)."""
        if self._pending is None or self._local is not None:
            return 0
        return sum(not conn.poll() for conn in self._conns)

    def worker_cpu_seconds(self) -> float:
        """CPU seconds the worker processes have used so far, as of their last reply (0 in-process)."""
        return float(sum(self._worker_cpu))

    def close(self) -> None:
        for env in self._local or []:
            env.close()
        for conn in self._conns:
            try:
                conn.send(("close", None))
            except (BrokenPipeError, OSError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=5)   # reaped, so its CPU time counts in the parent's RUSAGE_CHILDREN
        self._conns, self._procs = [], []

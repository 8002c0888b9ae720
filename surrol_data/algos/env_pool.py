"""Many envs in few worker processes: the batched training path's collector and evaluator.

Gymnasium's ``AsyncVectorEnv`` runs one process per env. A batched run steps dozens of envs (every
member's episodes at once) on two cores, where one process per env would mostly cost context switches
and pipe messages. Here each worker process holds a slice of the envs and steps its whole slice per
message, and the parent can do other work between :meth:`EnvPool.step_async` and :meth:`EnvPool.step_wait`
(the learner's updates: that is how collection and updates overlap).

Every env is reset with an explicit seed for every episode and stepped exactly ``max_episode_steps`` times
by its caller, so no auto-reset is involved and an episode depends on its seed and actions only, whichever
worker ran it.
"""

from __future__ import annotations

import multiprocessing as mp
from functools import partial

import numpy as np

INFO_KEYS = ("is_success", "tip_position", "jaw_angle")


def _stack_obs(obs_list: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]}


def _stack_info(infos: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([np.asarray(info[k], np.float32) for info in infos]) for k in INFO_KEYS if k in infos[0]}


def _worker(conn, env_fn, n_envs: int) -> None:
    envs = [env_fn() for _ in range(n_envs)]
    try:
        while True:
            cmd, payload = conn.recv()
            if cmd == "reset":
                results = [env.reset(seed=int(seed)) for env, seed in zip(envs, payload)]
                conn.send((_stack_obs([r[0] for r in results]), _stack_info([r[1] for r in results])))
            elif cmd == "step":
                results = [env.step(a) for env, a in zip(envs, payload)]
                conn.send((_stack_obs([r[0] for r in results]), np.array([r[1] for r in results], np.float32),
                           _stack_info([r[4] for r in results])))
            elif cmd == "close":
                break
    except (KeyboardInterrupt, EOFError):
        pass
    finally:
        for env in envs:
            env.close()
        conn.close()


class EnvPool:
    """``n_envs`` copies of ``env_id`` spread over ``n_workers`` spawned processes (in-process for 0 workers)."""

    def __init__(self, env_id: str, max_episode_steps: int, n_envs: int, n_workers: int = 2):
        from surrol_data.algos.train import make_env

        if n_envs < 1 or n_workers < 0:
            raise ValueError(f"EnvPool needs n_envs >= 1 and n_workers >= 0, got {n_envs}, {n_workers}")
        self.n_envs = n_envs
        env_fn = partial(make_env, env_id, max_episode_steps)
        self._local = None
        self._conns, self._procs, self._sizes = [], [], []
        if n_workers == 0:
            self._local = [env_fn() for _ in range(n_envs)]
        else:
            n_workers = min(n_workers, n_envs)
            sizes = [n_envs // n_workers + (w < n_envs % n_workers) for w in range(n_workers)]
            # spawn, not fork: the parent already runs torch's thread pool, which a forked child must not inherit
            ctx = mp.get_context("spawn")
            for size in sizes:
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=_worker, args=(child, env_fn, size), daemon=True)
                proc.start()
                child.close()
                self._conns.append(parent)
                self._procs.append(proc)
                self._sizes.append(size)
        self._pending = None

    def _split(self, values) -> list:
        out, start = [], 0
        for size in self._sizes:
            out.append(values[start:start + size])
            start += size
        return out

    def reset(self, seeds: list[int]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Reset every env with its seed: (stacked obs, stacked info)."""
        if len(seeds) != self.n_envs:
            raise ValueError(f"EnvPool.reset needs one seed per env ({self.n_envs}), got {len(seeds)}")
        if self._local is not None:
            results = [env.reset(seed=int(s)) for env, s in zip(self._local, seeds)]
            return _stack_obs([r[0] for r in results]), _stack_info([r[1] for r in results])
        for conn, part in zip(self._conns, self._split(list(seeds))):
            conn.send(("reset", part))
        parts = [conn.recv() for conn in self._conns]
        return _concat([p[0] for p in parts]), _concat([p[1] for p in parts])

    def step_async(self, actions: np.ndarray) -> None:
        """Send one action per env; the workers step while the caller does something else."""
        if self._local is not None:
            results = [env.step(a) for env, a in zip(self._local, actions)]
            self._pending = (_stack_obs([r[0] for r in results]), np.array([r[1] for r in results], np.float32),
                             _stack_info([r[4] for r in results]))
            return
        for conn, part in zip(self._conns, self._split(np.asarray(actions, np.float32))):
            conn.send(("step", part))
        self._pending = True

    def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray]]:
        """(obs, reward, info) of the step sent by :meth:`step_async`, stacked over envs."""
        if self._pending is None:
            raise RuntimeError("step_wait without a step_async")
        if self._local is not None:
            out, self._pending = self._pending, None
            return out
        parts = [conn.recv() for conn in self._conns]
        self._pending = None
        return _concat([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), _concat([p[2] for p in parts])

    def step(self, actions: np.ndarray):
        self.step_async(actions)
        return self.step_wait()

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
        self._conns, self._procs = [], []


def _concat(parts: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

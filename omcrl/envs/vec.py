"""Vector envs: env 0 steps in the calling process, the others in worker processes, in parallel.

gymnasium's AsyncVectorEnv runs every env in a worker, sends each command and result through a pipe and the
calling process waits. On a small machine (2 cores, microVM) a pipe round trip plus two process wake-ups cost
~0.9 ms against a ~2.9 ms step at 64 px, and the caller's core idles while it waits. :class:`SplitVectorEnv`
instead

* steps env 0 itself while the workers step theirs, so the caller's core does useful work;
* hands actions, observations, rewards and flags over in shared memory (infos and errors as pickled bytes in
  a shared buffer), so a step moves no data through a pipe;
* signals with one semaphore per direction and worker, and spins on it briefly before blocking when there
  is a core per process, so nobody pays a wake-up in the common case (see ``SPIN_SECONDS``);
* lets a process that would only wait for another env's reset plan its own env's next reset meanwhile
  (``NavEnv.prefetch``; bit-identical results), so resets stall the lock-step less.

Semantics are gymnasium 1.x's ``SyncVectorEnv`` exactly (``tests/test_envs.py`` compares them step by step):
NEXT_STEP autoreset (the step after an episode ends returns the reset observation with reward 0 and no
flags, and ignores its action; ``info["metrics"]`` arrives with the step that ended the episode), infos
batched by gymnasium's own ``VectorEnv._add_info`` with ``_key`` masks.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import signal
import time
import traceback
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space, create_shared_memory, read_from_shared_memory

from omcrl.envs.nav_env import make_env
from omcrl.utils.runtime import cpu_count

# How long a waiting process spins on its semaphore before blocking. A blocked process lets its vCPU halt, and
# waking it again is most of what a hand-over costs in a microVM; the spin covers the usual turnaround (one env
# step, ~3 ms at 64 px) and gives the core back soon when nothing comes (during PPO updates). Only used when
# every process has a core of its own: with more processes than cores, spinning would steal the renderers' time.
SPIN_SECONDS = 0.005

# Bytes per worker for a pickled info dict or error (a reset info with its path is a few kB).
PAYLOAD_BYTES = 1 << 20

_STEP, _RESET, _CLOSE = 1, 2, 3
_OK, _ERROR = 0, 1


def _take(sem: Any, spin: float, alive: Callable[[], bool], lost: str) -> None:
    """Acquire ``sem``: non-blocking tries for up to ``spin`` s, then blocking waits of 1 s while ``alive()``.

    Raises
    ------
    RuntimeError : ``lost`` when ``alive()`` turns False while waiting (the other side died).
    """
    if spin > 0:
        end = time.perf_counter() + spin
        while not sem.acquire(False):
            if time.perf_counter() >= end:
                break
        else:
            return
    while not sem.acquire(timeout=1.0):
        if not alive():
            raise RuntimeError(lost)


class _Channel:
    """Shared memory of one worker: control words and a payload buffer for pickled objects."""

    def __init__(self, ctx: Any) -> None:
        # command, status, payload length (bytes), prefetch hint (to the worker), plan ready (from the worker)
        self.ctrl = ctx.RawArray("q", 5)
        self.buf = ctx.RawArray("B", PAYLOAD_BYTES)
        self.cmd = ctx.Semaphore(0)
        self.done = ctx.Semaphore(0)

    def put(self, obj: Any) -> None:
        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > PAYLOAD_BYTES:
            raise ValueError(
                f"vector env: a pickled info/command of {len(data)} bytes exceeds the {PAYLOAD_BYTES}-byte "
                "payload buffer (omcrl.envs.vec.PAYLOAD_BYTES)"
            )
        memoryview(self.buf).cast("B")[: len(data)] = data
        self.ctrl[2] = len(data)

    def get(self) -> Any:
        return pickle.loads(memoryview(self.buf).cast("B")[: self.ctrl[2]])


def _worker(
    slot: int,
    env_fn: Callable[[], gym.Env],
    ch: _Channel,
    obs_shm: Any,
    act_shm: Any,
    scal_shm: Any,
    obs_space: gym.Space,
    act_space: gym.Space,
    n: int,
    spin: float,
    parent: int,
) -> None:
    """Worker process: owns env ``slot``; serves step/reset/close commands until told to close."""
    # Ctrl-C reaches the whole process group: the caller handles it and closes the workers in order.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    obs = read_from_shared_memory(obs_space, obs_shm, n)
    act = read_from_shared_memory(act_space, act_shm, n)
    scal = np.frombuffer(scal_shm, np.float64).reshape(3, n)  # reward, terminated, truncated
    env = None
    autoreset = False
    parent_alive = lambda: os.getppid() == parent  # noqa: E731
    while True:
        try:
            _take(ch.cmd, spin, parent_alive, "parent gone")
        except RuntimeError:
            break  # the caller died without closing us
        cmd = ch.ctrl[0]
        try:
            if env is None:
                env = env_fn()
            if cmd == _CLOSE:
                env.close()
                ch.ctrl[1] = _OK
                ch.done.release()
                break
            if cmd == _RESET:
                seed, options = ch.get()
                o, info = env.reset(seed=seed, options=options)
                r, term, trunc = 0.0, False, False
            elif autoreset:
                o, info = env.reset()
                r, term, trunc = 0.0, False, False
            else:
                o, r, term, trunc, info = env.step(act[slot])
            autoreset = bool(term or trunc)
            _write(obs, slot, o)
            scal[:, slot] = (r, term, trunc)
            ch.put(info)
            ch.ctrl[1] = _OK
        except Exception as exc:  # handed to the caller, which raises it
            try:
                ch.put((exc, traceback.format_exc()))
            except Exception:  # unpicklable or too large: keep the text
                ch.put((RuntimeError(f"{type(exc).__name__}: {exc}"), traceback.format_exc()))
            ch.ctrl[1] = _ERROR
        ch.ctrl[4] = int(_has_plan(env))
        ch.done.release()
        if ch.ctrl[3]:  # another env is resetting: this process would only wait, so plan ahead
            _prefetch(env)
            ch.ctrl[4] = int(_has_plan(env))


def _has_plan(env: gym.Env | None) -> bool:
    """Whether ``env``'s next automatic reset is already planned (so it will be cheap)."""
    return bool(getattr(getattr(env, "unwrapped", None), "prefetched", False))


def _prefetch(env: gym.Env | None) -> None:
    """Let ``env`` plan its next reset now if it can (``NavEnv.prefetch``); results are unchanged."""
    fn = getattr(getattr(env, "unwrapped", None), "prefetch", None)
    if fn is not None:
        try:
            fn()
        except Exception:  # the reset itself recomputes the plan and raises whatever is wrong
            pass


def _write(views: Any, slot: int, obs: Any) -> None:
    if isinstance(views, dict):
        for k, v in views.items():
            v[slot] = obs[k]
    else:
        views[slot] = obs


def _empty_like(views: Any) -> Any:
    if isinstance(views, dict):
        return {k: np.empty_like(v) for k, v in views.items()}
    return np.empty_like(views)


class SplitVectorEnv(gym.vector.VectorEnv):
    """``n`` envs: env 0 stepped directly in this process, envs 1..n-1 each in a worker process.

    Results equal ``SyncVectorEnv``'s exactly (same NEXT_STEP autoreset, infos batched with gymnasium's
    ``_add_info``). An exception in a worker is raised here with the worker's traceback as a note; a worker
    that dies is reported instead of waited for.

    Parameters
    ----------
    env_fns : ``n >= 2`` zero-argument env constructors; all envs must share their spaces.
    spin : seconds to spin before blocking while waiting; default ``SPIN_SECONDS`` when every process has
        a core of its own, else 0.
    """

    def __init__(self, env_fns: list, spin: float | None = None) -> None:
        if len(env_fns) < 2:
            raise ValueError(f"SplitVectorEnv needs at least 2 envs, got {len(env_fns)}")
        self.num_envs = n = len(env_fns)
        self.spin = (SPIN_SECONDS if n <= cpu_count() else 0.0) if spin is None else float(spin)
        self.local = env_fns[0]()
        self.single_observation_space = self.local.observation_space
        self.single_action_space = self.local.action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self.metadata = {**getattr(self.local, "metadata", {}), "autoreset_mode": AutoresetMode.NEXT_STEP}
        self.render_mode = None
        self.closed = False
        self._autoreset = np.zeros(n, np.bool_)  # NEXT_STEP: these envs reset on the next step

        ctx = mp.get_context("fork")  # workers inherit the env constructors; nothing is pickled
        obs_shm = create_shared_memory(self.single_observation_space, n, ctx)
        act_shm = create_shared_memory(self.single_action_space, n, ctx)
        scal_shm = ctx.RawArray("d", 3 * n)
        self._obs = read_from_shared_memory(self.single_observation_space, obs_shm, n)
        self._act = read_from_shared_memory(self.single_action_space, act_shm, n)
        self._scal = np.frombuffer(scal_shm, np.float64).reshape(3, n)
        self._channels = [_Channel(ctx) for _ in range(1, n)]
        self._procs = []
        for slot, (fn, ch) in enumerate(zip(env_fns[1:], self._channels), start=1):
            args = (slot, fn, ch, obs_shm, act_shm, scal_shm, self.single_observation_space)
            args += (self.single_action_space, n, self.spin, os.getpid())
            p = ctx.Process(target=_worker, args=args, name=f"omcrl-vec-{slot}", daemon=True)
            p.start()
            self._procs.append(p)

    # ------------------------------------------------------------------ protocol
    def _send(self, cmd: int, payloads: list | None = None, hints: list[int] | None = None) -> None:
        """Give worker i (slot i + 1) ``cmd``, ``payloads[i]`` and prefetch hint ``hints[i]`` (default 0)."""
        for i, ch in enumerate(self._channels):
            ch.ctrl[0] = cmd
            ch.ctrl[3] = hints[i] if hints is not None else 0
            if payloads is not None:
                ch.put(payloads[i])
            ch.cmd.release()

    def _collect(self) -> list[Any]:
        """Wait for every worker's answer; their unpickled payloads in slot order (1..n-1)."""
        out, error = [], None
        for slot, (ch, p) in enumerate(zip(self._channels, self._procs), start=1):
            _take(ch.done, self.spin, p.is_alive, f"vector env worker {slot} died (exit code {p.exitcode})")
            payload = ch.get()
            if ch.ctrl[1] == _ERROR:
                exc, tb = payload
                exc.add_note(f"raised in vector env worker {slot}:\n{tb}")
                error = error or exc
            out.append(payload)
        if error is not None:
            raise error
        return out

    # ------------------------------------------------------------------ gym API
    def _check_open(self, what: str) -> None:
        if self.closed:
            raise RuntimeError(f"SplitVectorEnv.{what} called on a closed vector env")

    def reset(self, *, seed: int | list | None = None, options: dict | None = None) -> tuple[Any, dict]:
        self._check_open("reset")
        n = self.num_envs
        if seed is None:
            seed = [None] * n
        elif isinstance(seed, int):
            seed = [seed + i for i in range(n)]
        if len(seed) != n:
            raise ValueError(f"reset: got {len(seed)} seeds, expected num_envs={n}")
        if options and "reset_mask" in options:
            raise ValueError("reset: options['reset_mask'] is not supported by SplitVectorEnv")
        self._send(_RESET, [(seed[slot], options) for slot in range(1, n)])
        obs, infos, _ = self._finish(lambda: (*self.local.reset(seed=seed[0], options=options), 0.0, False, False))
        self._autoreset[:] = False
        return obs, infos

    def step(self, actions: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict]:
        self._check_open("step")
        actions = np.asarray(actions)
        if actions.shape != self._act.shape:
            raise ValueError(f"step: actions of shape {actions.shape}, expected {self._act.shape} (n_envs, action)")
        self._act[:] = actions
        # Envs that reset in this step keep the others waiting (a reset that was not planned ahead costs
        # several steps): the waiting processes use that time to plan their own next reset (NavEnv.prefetch).
        resetting = self._autoreset
        planned = np.array([_has_plan(self.local)] + [bool(ch.ctrl[4]) for ch in self._channels])
        slow = resetting & ~planned
        others = int(slow.sum()) - slow
        self._send(_STEP, hints=[int(others[i] > 0 and not resetting[i]) for i in range(1, self.num_envs)])

        def local() -> tuple:
            if resetting[0]:
                return (*self.local.reset(), 0.0, False, False)
            o, r, term, trunc, info = self.local.step(self._act[0])
            if others[0] > 0:  # not while resetting: then this process is the one being waited for
                _prefetch(self.local)
            return o, info, r, term, trunc

        obs, infos, scal = self._finish(local)
        rewards = scal[0].copy()
        terminated, truncated = scal[1].astype(np.bool_), scal[2].astype(np.bool_)
        self._autoreset = terminated | truncated
        return obs, rewards, terminated, truncated, infos

    def _finish(self, local: Callable[[], tuple]) -> tuple[Any, dict, np.ndarray]:
        """Run env 0 (``local()`` -> obs, info, reward, terminated, truncated) while the workers run the
        command already sent; batch env 0's results before waiting, the workers' after (fresh arrays)."""
        try:
            o, info, r, term, trunc = local()
            obs = _empty_like(self._obs)
            _write(obs, 0, o)
            self._scal[:, 0] = (r, term, trunc)
            infos = self._add_info({}, info, 0)
        finally:
            remote = self._collect()  # even when env 0 failed: the workers' answers must be consumed
        if isinstance(obs, dict):
            for k, v in obs.items():
                v[1:] = self._obs[k][1:]
        else:
            obs[1:] = self._obs[1:]
        for i, info in enumerate(remote, start=1):
            infos = self._add_info(infos, info, i)
        return obs, infos, self._scal

    def __del__(self) -> None:
        # Like gymnasium's AsyncVectorEnv: a vector env dropped without close() must not leave workers behind.
        try:
            if not getattr(self, "closed", True):
                self.close()
        except Exception:  # pragma: no cover - best effort at interpreter shutdown
            pass

    def close_extras(self, **kwargs: Any) -> None:
        self.local.close()
        for ch, p in zip(self._channels, self._procs):
            if p.is_alive():
                ch.ctrl[0] = _CLOSE
                ch.cmd.release()
        for p in self._procs:
            p.join(timeout=5.0)
            if p.is_alive():  # pragma: no cover - a wedged worker
                p.terminate()
                p.join()


def env_factory(scene: str, seed: int, kwargs: dict) -> Any:
    """A zero-argument builder of ``make_env(scene, seed=seed, **kwargs)`` for a vector env's worker."""

    def thunk() -> gym.Env:
        # Each worker is its own process with one core at most: keep its BLAS/torch single-threaded.
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        return make_env(scene, seed=seed, **kwargs)

    return thunk


def make_vec_env(
    scene: str, n_envs: int, seed: int = 0, asynchronous: bool = True, **env_kwargs: Any
) -> gym.vector.VectorEnv:
    """``n_envs`` copies of ``make_env(scene, ...)``; env i is seeded with ``seed + i``.

    ``asynchronous=True`` (default) runs them in parallel with :class:`SplitVectorEnv` (env 0 in this
    process, the rest in worker processes); ``False`` gives a SyncVectorEnv (one process, same semantics),
    useful for debugging. One env is always a SyncVectorEnv.
    """
    if n_envs < 1:
        raise ValueError(f"n_envs: got {n_envs}, expected >= 1")
    fns = [env_factory(scene, seed + i, env_kwargs) for i in range(n_envs)]
    if asynchronous and n_envs > 1:
        return SplitVectorEnv(fns)
    return gym.vector.SyncVectorEnv(fns)

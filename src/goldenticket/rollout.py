"""Batched Monte-Carlo rollouts: (noise source, seed) episodes -> per-episode results."""

from __future__ import annotations

import ctypes
import math
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from goldenticket.errors import OptionError, UserError
from goldenticket.factories import call_users, picklable
from goldenticket.local_pool import LocalPool, WorkerDied
from goldenticket.noise import NoiseSource
from goldenticket.objectives import OBJECTIVES, PROGRESS_OBJECTIVES
from goldenticket.policies import NoisePolicy, for_task, load_policy, policy_label
from goldenticket.shared_model import PolicyServer
from goldenticket.tasks import Task
from goldenticket.tasks.base import observation_digest, stack


@dataclass(frozen=True)
class Episode:
    source: NoiseSource
    seed: int


NONFINITE = "nonfinite-action"  # the cause of an episode ended by a NaN or infinite action


@dataclass(frozen=True)
class EpisodeResult:
    seed: int
    success: bool
    ret: float  # the objective's return for this episode
    length: int
    wall_time: float
    actions: np.ndarray | None = None  # [length, A], the executed actions, when recorded
    cause: str | None = None  # NONFINITE: ended as a failure when the policy's action was not finite
    digest: str | None = field(default=None, compare=False)  # its initial observation's, when it ran


def rollout(policy: NoisePolicy, task: Task, episodes: Sequence[Episode],
            objective: str = "success", envs: list | None = None,
            record_actions: bool = False, step_timeout: float | None = None) -> list[EpisodeResult]:
    """Run episodes side by side: one batched policy call per replanning step for all live envs.

    An env leaves the batch when it succeeds, says it is done, or reaches `task.max_steps`; or,
    as a failure with cause NONFINITE and the objective's worst return, when the policy's actions
    for it are not finite. Each episode's result depends only on its (source, seed), never on its
    batch slot. `record_actions` keeps each episode's executed actions in its result. A multi-task
    policy acts conditioned on `task`. An exception in the policy's or env's code is a one-line
    UserError naming the call and the user's file and line; a call that runs longer than
    `step_timeout` seconds (0 or None: no limit) is a one-line CallTimedOut (`TimeLimit`).
    """
    with (limit := TimeLimit(step_timeout)).armed():
        return _rollout(policy, task, episodes, objective, envs, record_actions, limit)


def _rollout(policy: NoisePolicy, task: Task, episodes: Sequence[Episode], objective: str,
             envs: list | None, record_actions: bool, limit: TimeLimit) -> list[EpisodeResult]:
    policy, n = for_task(policy, task), len(episodes)
    acting, resetting, stepping = (f"policy {policy_label(policy)!r}: act()", f"task {task.name!r}: reset()",
                                   f"task {task.name!r}: step()")
    envs = [] if envs is None else envs
    envs += [task.make_env() for _ in range(n - len(envs))]
    start = time.perf_counter()
    on_seed = [f"seed {ep.seed}" for ep in episodes]  # where a call that runs too long was
    obs = [limit.call(envs[i].reset, resetting, on_seed[i], ep.seed) for i, ep in enumerate(episodes)]
    digests = [observation_digest(o) for o in obs]
    history = getattr(policy, "n_obs_steps", 1)  # how many recent observations act sees (docs/contracts.md)
    recent = [deque([o] * history, maxlen=history) for o in obs]
    # act reads a chunk's last `history` observations: an env with step_unseen skips drawing the others
    skips = bool(envs) and callable(getattr(envs[0], "step_unseen", None))
    unseen, stepping_unseen = (policy.n_exec - history if skips else 0), f"task {task.name!r}: step_unseen()"
    samplers = [ep.source.sampler(ep.seed, policy.noise_shape) for ep in episodes]
    length = np.zeros(n, dtype=int)
    success, done = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    causes: list[str | None] = [None] * n
    live, executed = list(range(n)), [[] for _ in range(n)]
    while live:
        noise = np.stack([samplers[i]() for i in live])
        batch = partial(_seeds_of, task.name, episodes, list(live))  # said only if the call runs too long
        actions = limit.call(policy.act, acting, batch, stack([observed(recent[i]) for i in live]), noise)
        chunks = checked_actions(policy, actions, len(live))
        for i, chunk, finite in zip(live, chunks, np.isfinite(chunks).all(axis=(1, 2)), strict=True):
            if not finite:
                causes[i] = NONFINITE
                continue
            for j, action in enumerate(chunk):
                if j < unseen:
                    success[i], done[i] = limit.call(envs[i].step_unseen, stepping_unseen, on_seed[i], action)
                else:
                    observation, success[i], done[i] = limit.call(envs[i].step, stepping, on_seed[i], action)
                    recent[i].append(observation)
                length[i] += 1
                if record_actions:
                    executed[i].append(action)
                if success[i] or done[i] or length[i] >= task.max_steps:
                    break
        live = [i for i in live if not (success[i] or done[i] or causes[i]) and length[i] < task.max_steps]
    wall = (time.perf_counter() - start) / max(n, 1)  # episodes ran side by side: the mean
    score = OBJECTIVES[objective]
    reads_progress = objective in PROGRESS_OBJECTIVES  # else no env is asked: progress() costs a reward call
    returns = [score(False, task.max_steps, task.max_steps, 0.0) if causes[i] else
               score(bool(success[i]), int(length[i]), task.max_steps,
                     _progress(envs[i], success[i], task.name, limit, on_seed[i]) if reads_progress else 0.0)
               for i in range(n)]
    return [EpisodeResult(ep.seed, bool(success[i]), returns[i], int(length[i]), wall,
                          np.array(executed[i]) if record_actions else None, causes[i], digests[i])
            for i, ep in enumerate(episodes)]


def _seeds_of(task: str, episodes: Sequence[Episode], batch: list[int]) -> str:
    """Where a batched policy call was: the task and its episodes' seeds."""
    return f"task {task!r}, seeds {', '.join(str(episodes[i].seed) for i in batch)}"


def _progress(env, success: bool, task: str, limit: TimeLimit, on_seed: str) -> float:
    """1 for a success, else the env's own progress() in [0, 1] where it has one, else 0."""
    if success:
        return 1.0
    progress = getattr(env, "progress", None)
    if not callable(progress):
        return 0.0
    return min(1.0, max(0.0, float(limit.call(progress, f"task {task!r}: progress()", on_seed))))


def observed(recent: deque):
    """What act gets of one episode: its latest observation or, for a policy with n_obs_steps > 1, its
    last n_obs_steps stacked oldest first (the first observation repeated at the start)."""
    return recent[0] if len(recent) == 1 else stack(list(recent))


def checked_actions(policy: NoisePolicy, actions: np.ndarray, batch: int) -> np.ndarray:
    """The policy's actions if they have the contract's shape [B, n_exec, A] and are real numbers
    (NaN and infinities included: rollout ends those episodes)."""
    actions = np.asarray(actions)
    expected = (batch, policy.n_exec, getattr(policy, "action_dim", policy.noise_shape[1]))
    if actions.shape != expected:
        raise UserError(f"policy {policy_label(policy)!r} returned actions of shape {actions.shape}; the "
                        f"NoisePolicy contract asks for [B, n_exec, A] = {expected}")
    if actions.dtype.kind not in "fiu":
        raise UserError(f"policy {policy_label(policy)!r} returned actions of dtype {actions.dtype}; the "
                        "NoisePolicy contract asks for real numbers (float)")
    return actions


class CallTimedOut(OptionError):
    """A call of the user's (an env's reset or step, a policy's act) ran longer than step_timeout."""

    def __init__(self, message: str = ""):  # raised bare by TimeLimit's clocks, then with its message
        super().__init__(message, "step_timeout")


class TimeLimit:
    """Ends a call of the user's that runs longer than `seconds` (0 or None: no limit) with a one-line
    CallTimedOut naming it. While `armed`, a clock checks the call running ten times per limit: in the
    main thread (an in-process run, every local worker and Ray actor) a SIGALRM timer, whose exception
    also ends a sleep or a wait for a socket; in another thread a watcher thread, whose exception comes
    at the calling thread's next Python instruction. A call stuck inside C code ends when it returns."""

    def __init__(self, seconds: float | None):
        self.seconds = seconds or None
        self._running, self._started = ("", ""), math.inf  # the call timed (what, where), and since when

    def call(self, fn: Callable, what: str, where: str | Callable[[], str], *args):
        """`call_users(fn, what, *args)`, timed; `where`: the episodes it is for (`task 'x', seed 3`), or a
        function saying it, called only if the call runs too long."""
        self._running, self._started = (what, where), time.monotonic()
        try:
            return call_users(fn, what, *args)
        finally:
            self._started = math.inf

    @contextmanager
    def armed(self) -> Iterator[None]:
        """Times the calls made in the block."""
        if self.seconds is None:
            yield
            return
        clock = self._alarm if threading.current_thread() is threading.main_thread() else self._watcher
        try:
            with clock(self.seconds / 10):
                yield
        except CallTimedOut:
            what, where = self._running
            where = where() if callable(where) else where
            raise CallTimedOut(f"{what} on {where} did not return within step_timeout {self.seconds:g} s (a "
                               "slow simulator or model needs a larger one; 0: no limit)") from None

    def _overdue(self) -> bool:
        return time.monotonic() - self._started > self.seconds

    @contextmanager
    def _alarm(self, tick: float) -> Iterator[None]:
        def check(signum, frame):
            if self._overdue():
                raise CallTimedOut

        previous = signal.signal(signal.SIGALRM, check)
        signal.setitimer(signal.ITIMER_REAL, tick, tick)
        try:
            yield
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous or signal.SIG_DFL)  # None: not set from Python

    @contextmanager
    def _watcher(self, tick: float) -> Iterator[None]:
        caller, stop = threading.get_ident(), threading.Event()

        def watch():
            while not stop.wait(tick):
                if self._overdue():
                    _raise_in(caller, CallTimedOut)

        watcher = threading.Thread(target=watch, name="step_timeout", daemon=True)
        watcher.start()
        try:
            yield
        finally:
            stop.set()
            watcher.join()
            _raise_in(caller, None)  # one sent but not yet raised is dropped


def _raise_in(thread: int, exception: type[BaseException] | None) -> None:
    """Raises `exception` in `thread` at its next Python instruction (None: drops one sent before)."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread),
                                               None if exception is None else ctypes.py_object(exception))


# --- process pool: each worker loads the policy and tasks once, then runs shards ---------------
_worker: dict = {}


def _init_worker(policy: str | NoisePolicy, tasks: dict[str, Task], objective: str, device: str,
                 step_timeout: float | None, settings: dict) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle
    torch.set_num_threads(1)
    _worker.update(policy=load_policy(policy, device, **settings), tasks=tasks, objective=objective,
                   envs={name: [] for name in tasks}, step_timeout=step_timeout)


def _run_shard(shard: tuple[str, list[Episode]]) -> list[EpisodeResult]:
    (task, episodes), w = shard, _worker
    return rollout(w["policy"], w["tasks"][task], episodes, w["objective"], w["envs"][task],
                   step_timeout=w["step_timeout"])


def _local_pool(workers: int, initializer, initargs: tuple, address: None) -> LocalPool:
    return LocalPool(workers, initializer, initargs)


def _ray_pool(workers: int, initializer, initargs: tuple, address: str | None):
    from goldenticket.ray_pool import RayPool

    return RayPool(workers, initializer, initargs, address)


BACKENDS = {"local": _local_pool, "ray": _ray_pool}


class Engine:
    """Evaluates episodes in-process (local backend, workers=1), across local worker processes,
    or on Ray actors (`backend="ray"`, a local Ray instance or the cluster at `address`).

    Shards are fixed by episode order, never by timing, so every backend gives the same
    results for the same episodes. `task` is one task or several (a multi-task policy's): each
    `evaluate` call names the task its episodes run on, the first by default.
    """

    def __init__(self, policy: str | NoisePolicy, task: Task | Sequence[Task], *, objective: str = "success",
                 workers: int = 1, shard_size: int = 16, backend: str = "local", address: str | None = None,
                 loaded: NoisePolicy | None = None, device: str = "cpu", share_model: bool | None = None,
                 step_timeout: float | None = None, settings: dict | None = None):
        """`policy` as workers rebuild it (a name, or the object pickled), on `device` with `settings`
        (a LeRobot checkpoint's rename_map and overrides, as `load_policy` takes them); `loaded`: the
        policy already built from it, used in-process instead of building it again. A shard's episodes run
        side by side, one env each: 16 fills one block of the bundled policies' batched call.
        `share_model` (by default: on a device other than the CPU, with local workers): the workers step
        their envs and act through one policy in this process (`shared_model.PolicyServer`).
        `step_timeout`: seconds an env's reset or step, or a policy call, may run (None: no limit),
        wherever it runs (`TimeLimit`)."""
        most = 4 * (os.cpu_count() or 1)
        if backend not in BACKENDS:
            raise OptionError(f"unknown backend {backend!r}; choose from {list(BACKENDS)}", "backend")
        if address is not None and backend != "ray":
            raise OptionError("address needs backend ray", "address", "backend")
        if workers < 1 or (backend == "local" and workers > most):
            raise OptionError(f"workers must be between 1 and {most} (4 per CPU here), got {workers}",
                              "workers")
        local = backend == "local" and workers == 1
        if share_model is None:
            share_model = device != "cpu" and backend == "local"
        shared = share_model and not local
        settings = settings or {}
        self.policy = (loaded or load_policy(policy, device, **settings)) if local or shared else None
        self.label, self.in_workers = policy_label(loaded or policy), not local  # for messages
        self.tasks = {t.name: t for t in ([task] if hasattr(task, "make_env") else task)}
        self.task = next(iter(self.tasks.values()))
        self.objective, self.shard_size, self.step_timeout = objective, shard_size, step_timeout
        self._envs: dict[str, list] = {name: [] for name in self.tasks}
        self._pool, self._server = None, PolicyServer(self.policy) if shared else None
        if self._server:
            policy, device, settings = self._server.client(), "cpu", {}
        if not local:  # each worker rebuilds a named policy, or unpickles a policy object
            picklable((policy, self.tasks), f"policy {policy_label(policy)!r} or task {self.task.name!r}")
            initargs = (policy, self.tasks, objective, device, step_timeout, settings)
            self._pool = BACKENDS[backend](workers, _init_worker, initargs, address)

    def evaluate(self, episodes: Sequence[Episode],
                 on_shard: Callable[[int, list[EpisodeResult]], None] | None = None,
                 task: str | None = None) -> list[EpisodeResult]:
        """Results in episode order, on `task` (a name; default the first task); `on_shard(start,
        results)` as each shard finishes."""
        task = task or self.task.name
        starts = range(0, len(episodes), self.shard_size)
        shards = [(task, list(episodes[i : i + self.shard_size])) for i in starts]
        if self._pool is None:
            runs = (rollout(self.policy, self.tasks[t], s, self.objective, self._envs[t],
                            step_timeout=self.step_timeout) for t, s in shards)
        else:
            runs = self._pool.imap(_run_shard, shards)
        results: list[EpisodeResult] = []
        try:
            for start, shard_results in zip(starts, runs, strict=True):
                results += shard_results
                if on_shard:
                    on_shard(start, shard_results)
        except WorkerDied as exc:  # hand on the shards that came back before it
            for index, shard_results in sorted(exc.finished.items()):
                if on_shard:
                    on_shard(starts[index], shard_results)
            raise UserError(f"{exc} while running episodes of {self.label!r} on {task!r}") from None
        return results

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool = None
        if self._server is not None:
            self._server.close()
            self._server = None

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""Batched Monte-Carlo rollouts: (noise source, seed) episodes -> per-episode results."""

from __future__ import annotations

import os
import signal
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

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
            record_actions: bool = False) -> list[EpisodeResult]:
    """Run episodes side by side: one batched policy call per replanning step for all live envs.

    An env leaves the batch when it succeeds, says it is done, or reaches `task.max_steps`; or,
    as a failure with cause NONFINITE and the objective's worst return, when the policy's actions
    for it are not finite. Each episode's result depends only on its (source, seed), never on its
    batch slot. `record_actions` keeps each episode's executed actions in its result. A multi-task
    policy acts conditioned on `task`. An exception in the policy's or env's code is a one-line
    UserError naming the call and the user's file and line.
    """
    policy, n = for_task(policy, task), len(episodes)
    acting, resetting, stepping = (f"policy {policy_label(policy)!r}: act()", f"task {task.name!r}: reset()",
                                   f"task {task.name!r}: step()")
    envs = [] if envs is None else envs
    envs += [task.make_env() for _ in range(n - len(envs))]
    start = time.perf_counter()
    obs = [call_users(env.reset, resetting, ep.seed) for env, ep in zip(envs, episodes, strict=False)]
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
        actions = call_users(policy.act, acting, stack([observed(recent[i]) for i in live]), noise)
        chunks = checked_actions(policy, actions, len(live))
        for i, chunk, finite in zip(live, chunks, np.isfinite(chunks).all(axis=(1, 2)), strict=True):
            if not finite:
                causes[i] = NONFINITE
                continue
            for j, action in enumerate(chunk):
                if j < unseen:
                    success[i], done[i] = call_users(envs[i].step_unseen, stepping_unseen, action)
                else:
                    observation, success[i], done[i] = call_users(envs[i].step, stepping, action)
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
                     _progress(envs[i], success[i], task.name) if reads_progress else 0.0)
               for i in range(n)]
    return [EpisodeResult(ep.seed, bool(success[i]), returns[i], int(length[i]), wall,
                          np.array(executed[i]) if record_actions else None, causes[i], digests[i])
            for i, ep in enumerate(episodes)]


def _progress(env, success: bool, task: str) -> float:
    """1 for a success, else the env's own progress() in [0, 1] where it has one, else 0."""
    if success:
        return 1.0
    progress = getattr(env, "progress", None)
    if not callable(progress):
        return 0.0
    return min(1.0, max(0.0, float(call_users(progress, f"task {task!r}: progress()"))))


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


# --- process pool: each worker loads the policy and tasks once, then runs shards ---------------
_worker: dict = {}


def _init_worker(policy: str | NoisePolicy, tasks: dict[str, Task], objective: str, device: str) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle
    torch.set_num_threads(1)
    _worker.update(policy=load_policy(policy, device), tasks=tasks, objective=objective,
                   envs={name: [] for name in tasks})


def _run_shard(shard: tuple[str, list[Episode]]) -> list[EpisodeResult]:
    (task, episodes), w = shard, _worker
    return rollout(w["policy"], w["tasks"][task], episodes, w["objective"], w["envs"][task])


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
                 loaded: NoisePolicy | None = None, device: str = "cpu", share_model: bool | None = None):
        """`policy` as workers rebuild it (a name, or the object pickled), on `device`; `loaded`: the
        policy already built from it, used in-process instead of building it again. A shard's episodes run
        side by side, one env each: 16 fills one block of the bundled policies' batched call.
        `share_model` (by default: on a device other than the CPU, with local workers): the workers step
        their envs and act through one policy in this process (`shared_model.PolicyServer`)."""
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
        self.policy = (loaded or load_policy(policy, device)) if local or shared else None
        self.label, self.in_workers = policy_label(loaded or policy), not local  # for messages
        self.tasks = {t.name: t for t in ([task] if hasattr(task, "make_env") else task)}
        self.task = next(iter(self.tasks.values()))
        self.objective, self.shard_size = objective, shard_size
        self._envs: dict[str, list] = {name: [] for name in self.tasks}
        self._pool, self._server = None, PolicyServer(self.policy) if shared else None
        if self._server:
            policy, device = self._server.client(), "cpu"
        if not local:  # each worker rebuilds a named policy, or unpickles a policy object
            picklable((policy, self.tasks), f"policy {policy_label(policy)!r} or task {self.task.name!r}")
            initargs = (policy, self.tasks, objective, device)
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
            runs = (rollout(self.policy, self.tasks[t], s, self.objective, self._envs[t]) for t, s in shards)
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

"""The task contract: seeded envs, observation digests (and traces of seeded episodes), quiet env
creation."""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from goldenticket.errors import UserError
from goldenticket.factories import call_users


def observation_digest(obs) -> str:
    """sha256 of one observation: an array, or a dict of arrays (or of such dicts: cameras) key by
    key, in sorted order."""
    digest = hashlib.sha256()
    parts = obs.items() if isinstance(obs, dict) else [("", obs)]
    for key, value in sorted(parts, key=lambda kv: kv[0]):
        data = observation_digest(value).encode() if isinstance(value, dict) else np.ascontiguousarray(value)
        digest.update(json.dumps(key).encode() + (data if isinstance(data, bytes) else data.tobytes()))
    return digest.hexdigest()


def stack(observations: list, join: Callable = np.stack) -> np.ndarray | dict[str, np.ndarray]:
    """One batch from per-env observations (arrays, or dicts of arrays or of such dicts, joined key by
    key); `join=np.concatenate` joins batches into one."""
    if isinstance(observations[0], dict):
        return {key: stack([o[key] for o in observations], join) for key in observations[0]}
    return join(observations)


Episode = list[dict[str, str]]  # its observations' digests by key ("" for an array), the reset's first
FIRST_ENV = "in one env"  # where a trace's first episodes ran: the others must repeat them


def trace(task, seeds: Sequence[int], steps: int, env: Env | None = None) -> dict[str, list[Episode]]:
    """The seeds' `episodes` by where they ran in this process: in one env (`env`, else a new one),
    then the first seed's again in it after them and in a new env (a reset can cost seconds: LIBERO
    rebuilds its scene); what `goldenticket.checks` compares."""
    env = task.make_env() if env is None else env
    return {FIRST_ENV: episodes(task, seeds, steps, env),
            "in the same env after other episodes": episodes(task, seeds[:1], steps, env),
            "in a new env": episodes(task, seeds[:1], steps)}


def episodes(task, seeds: Sequence[int], steps: int, env: Env | None = None) -> list[Episode]:
    """Each seed's episode through `steps` fixed actions, one after another in one env (`env`, else a
    new one)."""
    env = task.make_env() if env is None else env
    return [episode(task, env, seed, steps) for seed in seeds]


def episode(task, env: Env, seed: int, steps: int) -> Episode:
    """`seed`'s episode through `steps` fixed actions, until the env says done or succeeded; the env's
    failure is one line."""
    observations = [call_users(env.reset, f"task {task.name!r}: reset()", seed)]
    for action in fixed_actions(task, env, steps):
        obs, success, done = call_users(env.step, f"task {task.name!r}: step()", action)
        observations.append(obs)
        if success or done:
            break
    return [{key: observation_digest(value) for key, value in obs.items()} if isinstance(obs, dict)
            else {"": observation_digest(obs)} for obs in observations]


def fixed_actions(task, env: Env, steps: int) -> list:
    """`steps` actions, the same in every process: uniform in [-1, 1] where the task names its action
    size (`action_dim`), else drawn from the env's action space (a Gymnasium env's), seeded."""
    size = getattr(task, "action_dim", None)
    if size is not None:
        return list(np.random.default_rng(0).uniform(-1, 1, (steps, size)))
    space = getattr(env, "action_space", None)
    if space is None:
        raise UserError(f"task {task.name!r}: its env has no action_space to draw actions from")
    space.seed(0)
    return [space.sample() for _ in range(steps)]


@functools.cache
def quiet_robosuite_logs() -> None:
    """Keep only robosuite's errors (its advice on macro files and its controller notes are noise to our
    users); a filter, since robosuite sets its logger's level when imported."""
    logging.getLogger("robosuite_logs").addFilter(lambda record: record.levelno >= logging.ERROR)


@functools.cache
def quiet_env_warnings() -> None:
    """Silence warnings raised from inside gymnasium and metaworld (the passive env checker's),
    so users see our output; installed once per process."""
    warnings.filterwarnings("ignore", module=r"gymnasium(\.|$)")
    warnings.filterwarnings("ignore", module=r"metaworld(\.|$)")


class Env(Protocol):
    """One environment instance whose initial state is a function of an integer seed.
    Observations are arrays or dicts of arrays."""

    def reset(self, seed: int) -> Any: ...

    def step(self, action: np.ndarray) -> tuple[Any, bool, bool]:
        """Apply one action; returns (observation, success, done). Rewards are not used."""
        ...

    # Optional: progress() -> float in [0, 1], how far the task got in the current state (a dense
    # tie-breaker between failed episodes, read once when an episode ends).
    # Optional: step_unseen(action) -> (success, done), a step whose observation no policy reads
    # (rollout calls it for all but a chunk's last n_obs_steps steps): an env that renders skips the frame.


class Task(Protocol):
    """Builds envs; worker processes receive the task pickled; `name` is what tickets record.
    `goldenticket.checks` checks every task's envs the same way before a run."""

    name: str
    max_steps: int
    # Optional: instruction: str | None, what a language policy (a VLA) is told to do, passed as
    # LeRobot passes it ("task"); Meta-World tasks have LeRobot's description of their env.
    # Optional: action_dim: int, the numbers of an action (else the env's action_space says).
    # Optional: note() -> None, says once (on stderr) what on this machine makes the task's numbers
    # differ from recorded ones (robomimic's: OpenBLAS's kernels); the checks call it.

    def make_env(self) -> Env: ...

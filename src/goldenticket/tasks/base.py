"""The task contract: seeded envs, observation digests, quiet env creation."""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import warnings
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from goldenticket.errors import UserError


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


CHECK_SEEDS, CHECK_STEPS = (0, 1_000_000), 3  # a search seed and a held-out one, a few actions each


def check_repeatable(task) -> None:
    """UserError unless the same seed and actions give the same observations: again after another
    episode in the same env, and in another process (the way workers rebuild the task)."""
    from goldenticket.factories import in_another_process

    first, once = episode_digests(task), CHECK_STEPS + 1
    elsewhere = in_another_process(episode_digests, task, what=f"task {task.name!r}")
    if first[:once] != first[-once:] or elsewhere != first:
        raise UserError(f"task {task.name!r}: the same seed and actions gave different observations; its "
                        "initial states are not repeatable on this machine")


def episode_digests(task) -> list[str]:
    """Digests of CHECK_SEEDS' episodes through a few fixed actions (in [-1, 1], `task.action_dim` of
    them) in one env, then of the first seed's again: an env whose state leaks across resets differs."""
    env = task.make_env()
    actions = np.random.default_rng(0).uniform(-1, 1, (CHECK_STEPS, task.action_dim))
    digests = []
    for seed in (*CHECK_SEEDS, CHECK_SEEDS[0]):
        digests.append(observation_digest(env.reset(seed)))
        digests += [observation_digest(env.step(action)[0]) for action in actions]
    return digests


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
    """Builds envs; worker processes receive the task pickled; `name` is what tickets record."""

    name: str
    max_steps: int
    # Optional: instruction: str | None, what a language policy (a VLA) is told to do, passed as
    # LeRobot passes it ("task"); Meta-World tasks have LeRobot's description of their env.

    def make_env(self) -> Env: ...

    def check(self) -> None:
        """UserError if the same seed does not give the same initial state."""

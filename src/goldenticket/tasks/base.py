"""The task contract: seeded envs, observation digests, quiet env creation."""

from __future__ import annotations

import functools
import hashlib
import json
import warnings
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np


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

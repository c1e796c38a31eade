"""Task contract, seed sets and objectives."""

from __future__ import annotations

import functools
import hashlib
import json
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from goldenticket.errors import UserError

# Disjoint by construction: a seed names one initial state and belongs to exactly one set.
SEED_SETS: dict[str, range] = {
    "search": range(0, 1_000_000),
    "heldout": range(1_000_000, 2_000_000),
    "train": range(2_000_000, 3_000_000),
    "validation": range(3_000_000, 4_000_000),  # selection among search tickets (--validation-seeds)
}


def seeds_in(seed_set: str, n: int) -> list[int]:
    """The first `n` seeds of a seed set."""
    if seed_set not in SEED_SETS:
        raise UserError(f"unknown seed set {seed_set!r}; choose from {sorted(SEED_SETS)}")
    block = SEED_SETS[seed_set]
    if not 0 <= n <= len(block):
        raise UserError(f"seed set {seed_set!r} has {len(block)} seeds; asked for {n}")
    return list(block[:n])


def require_unseen(seeds: Sequence[int], used: range, what: str) -> None:
    """UserError unless `seeds` avoid `used`: numbers on seen states would not be held-out."""
    if min(seeds) < used.stop and used.start <= max(seeds):
        raise UserError(f"seeds {min(seeds)}:{max(seeds) + 1} overlap the {what} "
                        f"({used.start}:{used.stop}); held-out seeds must be new")


def require_heldout(seeds: Sequence[int]) -> None:
    """UserError unless every seed is a held-out seed: verdicts need states nothing was fit on."""
    block = SEED_SETS["heldout"]
    if min(seeds) < block.start or max(seeds) >= block.stop:
        raise UserError(f"seeds {min(seeds)}:{max(seeds) + 1} are not all held-out seeds "
                        f"({block.start}:{block.stop}); a verdict needs states no search or training used")


def seed_set_of(seed: int) -> str:
    """Name of the set a seed belongs to."""
    for name, block in SEED_SETS.items():
        if seed in block:
            return name
    raise UserError(f"seed {seed} is outside every seed set")


def _discounted(success: bool, length: int, max_steps: int, progress: float, gamma: float = 0.99) -> float:
    return float(success) * gamma ** (length - 1)


PROGRESS_WEIGHT = 0.01  # below 1/n for n <= 100 episodes: a tie-breaker, never outweighs one success

# Episode return from (success, length, max_steps, progress); higher is better for every objective.
# progress: how far a failed episode got, in [0, 1] (Env.progress; 1 on success, 0 if unknown).
OBJECTIVES: dict[str, Callable[[bool, int, int, float], float]] = {
    "success": lambda success, length, max_steps, progress: float(success),
    "success-progress": lambda success, length, max_steps, progress: success + PROGRESS_WEIGHT * progress,
    "discounted-success": _discounted,
    "length": lambda success, length, max_steps, progress: -length / max_steps,
    "speed": lambda success, length, max_steps, progress: (1 - length / max_steps) if success else 0.0,
}
PROGRESS_OBJECTIVES = frozenset({"success-progress"})  # the objectives that read Env.progress()
FRONT_OBJECTIVES = tuple(o for o in OBJECTIVES if o not in PROGRESS_OBJECTIVES)  # from success, length


def observation_digest(obs) -> str:
    """sha256 of one observation: an array, or a dict of arrays key by key (in sorted order)."""
    digest = hashlib.sha256()
    parts = obs.items() if isinstance(obs, dict) else [("", obs)]
    for key, value in sorted(parts, key=lambda kv: kv[0]):
        digest.update(json.dumps(key).encode() + np.ascontiguousarray(value).tobytes())
    return digest.hexdigest()


def stack(observations: list, join: Callable = np.stack) -> np.ndarray | dict[str, np.ndarray]:
    """One batch from per-env observations (arrays, or dicts of arrays joined key by key);
    `join=np.concatenate` joins batches into one."""
    if isinstance(observations[0], dict):
        return {key: join([o[key] for o in observations]) for key in observations[0]}
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

    def make_env(self) -> Env: ...

    def check(self) -> None:
        """UserError if the same seed does not give the same initial state."""

"""Meta-World v3 tasks with initial states controlled by the seed, not by the env's history."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from goldenticket.tasks import metaworld_fast
from goldenticket.tasks.base import quiet_env_warnings


@cache
def _env_classes() -> dict:
    """Meta-World's v3 env classes, once the known warnings are quiet."""
    quiet_env_warnings()
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    return dict(ALL_V3_ENVIRONMENTS)


def task_names() -> list[str]:
    return sorted(f"metaworld/{name}" for name in _env_classes())


class MetaWorldEnv:
    """A goal-observable Meta-World env whose reset(seed) fixes object and goal positions.

    Meta-World draws initial positions from `np_random` in `_get_state_rand_vec` (with its own
    rejection loops for some tasks); we reseed that generator from the integer seed at every
    reset, and `MujocoEnv.reset` restores the simulator state, so history does not leak in.
    With `fast` (the default) the per-step Python is `metaworld_fast`'s bitwise-identical code;
    `fast=False` steps Meta-World's own, for comparison.
    """

    def __init__(self, env_name: str, fast: bool = True):
        self._env = _env_classes()[env_name]()
        env = self._env
        env._partially_observable = False  # the goal is part of the observation
        env.__dict__.pop("sawyer_observation_space", None)  # cached property: recompute
        env._set_task_called = True
        env._freeze_rand_vec = False
        env.seeded_rand_vec = True
        if fast:
            metaworld_fast.install(env, env_name)

    def reset(self, seed: int) -> np.ndarray:
        self._env.np_random = np.random.Generator(np.random.PCG64(seed))
        obs, _ = self._env.reset()
        return obs.astype(np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool, bool]:
        obs, _, terminated, truncated, info = self._env.step(np.asarray(action, dtype=np.float64))
        return obs.astype(np.float32), bool(info["success"]), bool(terminated or truncated)


@dataclass(frozen=True)
class MetaWorldTask:
    """A Meta-World v3 task, e.g. `metaworld/pick-place-v3`; episodes end at success."""

    name: str
    max_steps: int = 150
    obs_dim: int = 39
    action_dim: int = 4

    @property
    def env_name(self) -> str:
        return self.name.split("/", 1)[1]

    def make_env(self) -> MetaWorldEnv:
        return MetaWorldEnv(self.env_name)

    def check(self) -> None:
        """Nothing to check: reset(seed) reseeds the env's generator (tests/test_tasks.py)."""

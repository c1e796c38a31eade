"""Any Gymnasium environment as a task: a factory returning a `gymnasium.Env`, given as a callable
or as an import string `package.module:factory`.

`reset(seed=s)` must fix the initial state; success comes from `info["success"]` or
`info["is_success"]`, or from the user's predicate `success(obs, info) -> bool`; an episode ends
on success, `terminated`, `truncated` or the task's `max_steps`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from goldenticket.errors import UserError
from goldenticket.factories import build, import_name, is_import_string, resolve
from goldenticket.tasks.base import quiet_env_warnings
from goldenticket.tasks.registry import task_family

SUCCESS_KEYS = ("success", "is_success")


class GymEnv:
    """A `gymnasium.Env` behind the Env contract."""

    def __init__(self, env, task: str, success: Callable | None = None):
        self._env, self.task, self._success = env, task, success

    @property
    def action_space(self):
        return self._env.action_space

    def reset(self, seed: int):
        obs, _ = self._env.reset(seed=seed)
        return obs

    def step(self, action: np.ndarray):
        obs, _, terminated, truncated, info = self._env.step(action)
        return obs, self._succeeded(obs, info), bool(terminated or truncated)

    def _succeeded(self, obs, info: dict) -> bool:
        if self._success is not None:
            return bool(self._success(obs, info))
        key = next((k for k in SUCCESS_KEYS if k in info), None)
        if key is None:
            raise UserError(f"task {self.task!r}: step() returned no info['success'] or "
                            "info['is_success']; return one, or pass a success predicate")
        return bool(info[key])


def is_factory(task: str | Callable) -> bool:
    """A callable, or an import string `package.module:factory`."""
    return callable(task) or is_import_string(task)


@task_family("Gymnasium", matches=is_factory,
             examples=lambda: "package.module:factory for a Gymnasium env of yours", factories=True)
@dataclass(frozen=True)
class GymTask:
    """A Gymnasium env built by `factory` (a callable, or an import string), episodes capped at
    `max_steps`; `success` (a predicate `(obs, info) -> bool`, or its import string) replaces
    the info keys. Worker processes receive the task pickled, so callables must be importable."""

    factory: Callable | str
    max_steps: int = 1000
    success: Callable | str | None = None

    @property
    def name(self) -> str:
        """The import string of the factory: what tickets record as their task."""
        return self.factory if isinstance(self.factory, str) else import_name(self.factory)

    @cached_property
    def instruction(self) -> str | None:
        """The env's language instruction, for a policy that reads one: its `task_description`, as
        LeRobot's envs name it (else `task`), read from one env built for it; None if it has neither."""
        env = getattr(self.make_env()._env, "unwrapped", None)
        text = getattr(env, "task_description", None) or getattr(env, "task", None)
        return text if isinstance(text, str) else None

    def make_env(self) -> GymEnv:
        quiet_env_warnings()
        env = build(self.factory, "task")
        if not all(callable(getattr(env, m, None)) for m in ("reset", "step")):
            raise UserError(f"task {self.name!r}: the factory must return a gymnasium.Env, "
                            f"got {type(env).__name__}")
        if type(getattr(env, "unwrapped", env)).__module__.startswith("metaworld"):
            raise UserError(f"task {self.name!r}: Meta-World's own envs ignore reset(seed=) "
                            "(their initial positions follow the env's history); use the built-in task "
                            "metaworld/<env-name>")
        success = self.success
        if isinstance(success, str):
            success = resolve(success, "success predicate")
        return GymEnv(env, self.name, success)

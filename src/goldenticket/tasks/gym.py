"""Any Gymnasium environment as a task, named by an import string `package.module:factory`.

The factory returns a `gymnasium.Env` whose `reset(seed=s)` fixes the initial state; success
comes from `info["success"]` or `info["is_success"]`; an episode ends on success, `terminated`,
`truncated` or the task's `max_steps`.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from goldenticket.errors import UserError
from goldenticket.factories import build
from goldenticket.tasks.base import SEED_SETS, quiet_env_warnings

SUCCESS_KEYS = ("success", "is_success")
CHECK_SEEDS = (SEED_SETS["search"].start, SEED_SETS["heldout"].start)


class GymEnv:
    """A `gymnasium.Env` behind the Env contract."""

    def __init__(self, env, task: str):
        self._env, self._task = env, task

    def reset(self, seed: int):
        obs, _ = self._env.reset(seed=seed)
        return obs

    def step(self, action: np.ndarray):
        obs, reward, terminated, truncated, info = self._env.step(action)
        key = next((k for k in SUCCESS_KEYS if k in info), None)
        if key is None:
            raise UserError(f"task {self._task!r}: step() returned no info['success'] or "
                            "info['is_success']; the search needs one")
        return obs, float(reward), bool(info[key]), bool(terminated or truncated)


@dataclass(frozen=True)
class GymTask:
    """A Gymnasium env built by `name`, an import string; episodes are capped at `max_steps`."""

    name: str
    max_steps: int = 1000

    def make_env(self) -> GymEnv:
        quiet_env_warnings()
        env = build(self.name, "task")
        if not all(callable(getattr(env, m, None)) for m in ("reset", "step")):
            raise UserError(f"task {self.name!r}: the factory must return a gymnasium.Env, "
                            f"got {type(env).__name__}")
        if type(getattr(env, "unwrapped", env)).__module__.startswith("metaworld"):
            raise UserError(f"task {self.name!r}: Meta-World's own envs ignore reset(seed=) "
                            "(Metaworld issue #555); use the built-in task metaworld/<env-name>")
        return GymEnv(env, self.name)

    def check(self) -> None:
        """Like Gymnasium's check_reset_seed_determinism: the same seed must give the same initial
        observation twice in one env, in a new env and in another process."""
        env = self.make_env()
        first = observation_digest(env, CHECK_SEEDS)
        again = [observation_digest(env, CHECK_SEEDS), observation_digest(self.make_env(), CHECK_SEEDS),
                 self._digest_in_another_process()]
        if any(d != first for d in again):
            raise UserError(f"task {self.name!r}: reset(seed=s) does not fix the initial state (the "
                            "same seed gave different observations); seed every random draw of "
                            "reset from its seed")

    def _digest_in_another_process(self) -> str:
        code = ("import sys; from goldenticket.tasks.gym import GymTask, observation_digest, CHECK_SEEDS; "
                "print(observation_digest(GymTask(sys.argv[1]).make_env(), CHECK_SEEDS))")
        path = os.pathsep.join(p for p in sys.path if p)  # as multiprocessing gives its workers
        proc = subprocess.run([sys.executable, "-c", code, self.name], capture_output=True, text=True,
                              env=os.environ | {"PYTHONPATH": path}, timeout=600)
        if proc.returncode:
            raise UserError(f"task {self.name!r}: cannot be built in another process "
                            f"({(proc.stderr.strip().splitlines() or ['no output'])[-1]})")
        return proc.stdout.strip()


def observation_digest(env: GymEnv, seeds: Sequence[int]) -> str:
    """sha256 of the initial observations (arrays or dicts of arrays) after reset(seed)."""
    digest = hashlib.sha256()
    for seed in seeds:
        obs = env.reset(seed)
        parts = obs.items() if isinstance(obs, dict) else [("", obs)]
        for key, value in sorted(parts, key=lambda kv: kv[0]):
            digest.update(json.dumps(key).encode() + np.ascontiguousarray(value).tobytes())
    return digest.hexdigest()

"""What a run is of: its tasks, checked before anything runs, and how its files name them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from goldenticket.config import SearchConfig, named
from goldenticket.errors import OptionError
from goldenticket.policies import NoisePolicy, for_task, identity, policy_label
from goldenticket.tasks import get_task


@dataclass(frozen=True)
class Names:
    """How the run's files name its policy and task, what its tickets are found for (the policy's
    identity) and the episode settings they are found under (None: not one value)."""

    policy: str
    task: str
    fingerprint: str
    max_steps: int | None = None
    success: str | None = None

    @classmethod
    def of(cls, policy_ref: str | NoisePolicy, policy: NoisePolicy, task_name: str,
           max_steps: int | None = None, success: str | Callable | None = None) -> Names:
        """Names of `policy`, built from `policy_ref`, on the task named `task_name`."""
        return cls(policy_label(policy_ref), task_name, identity(policy), max_steps, named(success))


def checked_tasks(policy: NoisePolicy, cfg: SearchConfig) -> list:
    """The run's tasks, each one the policy can act on and whose reset(seed) fixes the initial
    state (UserError now, not mid-run)."""
    tasks = [get_task(name, cfg.max_steps, cfg.success) for name in cfg.tasks]
    if len({t.name for t in tasks}) < len(tasks):
        raise OptionError("a task is given twice", "task")
    for task in tasks:
        for_task(policy, task.name)
        task.check()
    return tasks


def shared(values) -> int | None:
    """The one value all of `values` share, else None."""
    distinct = set(values)
    return distinct.pop() if len(distinct) == 1 else None


def search_title(cfg: SearchConfig, names: Names) -> str:
    return f"{cfg.method} search: {names.policy} on {names.task}"

"""A run fixed before any episode: its config, the policy and its checked tasks, the seeds, how
its files name things, and the sub-space it searches."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from goldenticket import checks
from goldenticket.config import SearchConfig, named
from goldenticket.errors import OptionError
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import NoisePolicy, identity, policy_label
from goldenticket.seeds import seeds_in
from goldenticket.tasks import get_task
from goldenticket.ticket_search.subspace import Subspace
from goldenticket.tickets import zero_ticket


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


@dataclass(frozen=True)
class Seeds:
    """The run's seeds of each set: search, held-out and validation."""

    search: list[int]
    heldout: list[int]
    validation: list[int]

    @classmethod
    def of(cls, cfg: SearchConfig) -> Seeds:
        return cls(seeds_in("search", cfg.search_seeds), seeds_in("heldout", cfg.heldout),
                   seeds_in("validation", cfg.validation()))

    @property
    def heldout_span(self) -> tuple[int, int]:
        return self.heldout[0], self.heldout[-1]


@dataclass(frozen=True)
class Plan:
    """One run: `cfg`, the loaded `policy` on its `tasks`, their seeds, names and the sub-space
    searched. Search episodes go to the tasks in turn: seed key k runs task k mod T on search seed
    k div T (`where`), so every prefix the optimizer uses spreads evenly over the tasks."""

    cfg: SearchConfig
    policy: NoisePolicy
    tasks: tuple
    names: Names
    seeds: Seeds
    subspace: Subspace

    @classmethod
    def of(cls, cfg: SearchConfig, policy: NoisePolicy, tasks: list) -> Plan:
        names = Names.of(cfg.policy, policy, " + ".join(t.name for t in tasks),
                         shared(t.max_steps for t in tasks), cfg.success)
        return cls(cfg, policy, tuple(tasks), names, Seeds.of(cfg),
                   Subspace.parse(cfg.subspace, policy.noise_shape))

    @property
    def task_names(self) -> list[str]:
        return [t.name for t in self.tasks]

    @property
    def keys(self) -> list[int]:
        """The optimizer's seed keys, one per (task, search seed)."""
        return list(range(len(self.tasks) * len(self.seeds.search)))

    def where(self, key: int) -> tuple[str, int]:
        """The (task, search seed) a seed key runs on."""
        return self.task_names[key % len(self.tasks)], self.seeds.search[key // len(self.tasks)]

    def expand(self, searched: np.ndarray) -> np.ndarray:
        """The full (H, A) ticket of a searched array."""
        return self.subspace.expand(searched, self.policy.noise_shape)

    @functools.cached_property
    def base(self) -> Gaussian:
        """The policy as it is: fresh Gaussian noise from the run's seed."""
        return Gaussian(self.cfg.seed)

    @functools.cached_property
    def zero(self) -> Constant:
        return Constant(zero_ticket(self.policy.noise_shape).noise)

    @property
    def title(self) -> str:
        return f"{self.cfg.method} search: {self.names.policy} on {self.names.task}"


def checked_tasks(policy: NoisePolicy, cfg: SearchConfig) -> list:
    """The run's tasks, each one passing every check of `goldenticket.checks` with the policy (the
    policy acts on it and answers its noise, the same seed gives the same episode): UserError now,
    not mid-run."""
    tasks = [get_task(name, cfg.max_steps, cfg.success, cfg.env_option) for name in cfg.tasks]
    if len({t.name for t in tasks}) < len(tasks):
        raise OptionError("a task is given twice", "task")
    for task in tasks:
        checks.require(task, policy)
    return tasks


def shared(values) -> int | None:
    """The one value all of `values` share, else None."""
    distinct = set(values)
    return distinct.pop() if len(distinct) == 1 else None

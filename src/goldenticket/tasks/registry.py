"""Tasks by name: each task family (Meta-World, its camera tasks, LeRobot's envs, robomimic, the
user's own Gymnasium envs) registers itself here when its module is imported (`tasks/__init__.py`
imports them all), and `get_task` looks a name up among them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from goldenticket.errors import OptionError, UserError

if TYPE_CHECKING:
    from goldenticket.tasks.base import Task


@dataclass(frozen=True)
class TaskFamily:
    """Tasks `get_task` builds: those `matches(task)` accepts, made by `build(task, **options)`
    (options: `max_steps`, `success` for factories, `env_options` for a family that checks them);
    `examples()` is what the unknown-task line offers of them (called only then: it may import a
    simulator to list names)."""

    name: str
    matches: Callable[[str | Callable], bool]
    build: Callable[..., Task]
    examples: Callable[[], str]
    # takes the user's env factories (callables, import strings): asked before the name families, even
    # about a name; the only family a success predicate applies to; offered last ("or ...")
    factories: bool = False
    # `env_options(task, options)`: a one-line OptionError unless the task takes these settings of its
    # env (`env_option`); None: the family's tasks take none
    env_options: Callable[[str, dict], dict] | None = None


FAMILIES: list[TaskFamily] = []  # in the order they registered: the order names are offered in


def task_family(name: str, matches: Callable[[str | Callable], bool], examples: Callable[[], str],
                factories: bool = False, env_options: Callable[[str, dict], dict] | None = None
                ) -> Callable[[Callable[..., Task]], Callable[..., Task]]:
    """Decorator: registers the decorated builder (a task class, usually) as the family `name`."""

    def register(build: Callable[..., Task]) -> Callable[..., Task]:
        if any(family.name == name for family in FAMILIES):
            raise ValueError(f"task family {name!r} is already registered")
        FAMILIES.append(TaskFamily(name, matches, build, examples, factories, env_options))
        return build

    return register


def get_task(task: str | Callable, max_steps: int | None = None, success: Callable | str | None = None,
             env_options: dict | None = None) -> Task:
    """A built-in task by name (Meta-World's, robomimic's, LeRobot's simulated envs), or a Gymnasium env
    from a factory (a callable or an import string `pkg.mod:factory`) with an optional success predicate;
    `env_options`: settings of a LeRobot env's config, as `lerobot-eval --env.KEY=VALUE` takes them.
    Unknown names are a UserError listing a few valid ones."""
    if max_steps is not None and max_steps < 1:
        raise OptionError(f"max_steps must be >= 1, got {max_steps}", "max_steps")
    family = family_of(task)
    if success is not None and not (family and family.factories):
        raise OptionError(f"success applies to Gymnasium tasks; {task!r} has its own success signal",
                          "success")
    check_task(task, env_options)
    options = {"max_steps": max_steps, "success": success, "env_options": env_options or None}
    return family.build(task, **{key: value for key, value in options.items() if value is not None})


def check_task(task: str | Callable, env_options: dict | None = None) -> None:
    """UserError for a task no family accepts, or env options it does not take, before any is built."""
    family = family_of(task)
    if family is None:
        raise UserError(unknown_task(task))
    if not env_options:
        return
    if family.env_options is None:
        takers = " and ".join(f.name for f in FAMILIES if f.env_options)
        raise OptionError(f"env_option applies to {takers} tasks; {task!r} takes none", "env_option")
    family.env_options(task, env_options)


def family_of(task: str | Callable) -> TaskFamily | None:
    """The first family that accepts `task`: factory families first, then, for a name, the others in
    the order they registered."""
    asked = [family for family in FAMILIES if family.factories]
    if isinstance(task, str):
        asked += [family for family in FAMILIES if not family.factories]
    return next((family for family in asked if family.matches(task)), None)


def unknown_task(task: str) -> str:
    """The unknown-task line: the first name family's examples, then the others', then the factories'."""
    named = [family.examples() for family in FAMILIES if not family.factories]
    others = named[1:] + [f"or {family.examples()}" for family in FAMILIES if family.factories]
    return f"unknown task {task!r}; tasks look like: {named[0]} ({'; '.join(others)})"

"""Tasks by name: built-in Meta-World tasks, or any Gymnasium env by import string."""

from __future__ import annotations

from goldenticket.errors import UserError
from goldenticket.factories import is_import_string
from goldenticket.tasks.gym import GymTask
from goldenticket.tasks.metaworld import MetaWorldTask, task_names


def get_task(name: str, max_steps: int | None = None) -> MetaWorldTask | GymTask:
    """A built-in task by name, or a Gymnasium env named by an import string `pkg.mod:factory`;
    unknown names are a UserError listing a few valid ones."""
    if max_steps is not None and max_steps < 1:
        raise UserError(f"--max-steps must be >= 1, got {max_steps}")
    if is_import_string(name):
        return GymTask(name) if max_steps is None else GymTask(name, max_steps)
    if name not in task_names():
        hint = ", ".join(n for n in task_names() if "pick" in n or "reach" in n)
        raise UserError(f"unknown task {name!r}; tasks look like: {hint} (or package.module:factory "
                        "for a Gymnasium env of yours)")
    return MetaWorldTask(name) if max_steps is None else MetaWorldTask(name, max_steps)

"""Tasks by name: built-in Meta-World tasks, or any Gymnasium env by factory or import string."""

from __future__ import annotations

from collections.abc import Callable

from goldenticket.errors import OptionError, UserError
from goldenticket.factories import is_import_string
from goldenticket.tasks.gym import GymTask
from goldenticket.tasks.lerobot_envs import LeRobotEnvTask, is_lerobot_env_task
from goldenticket.tasks.metaworld import MetaWorldTask, task_names
from goldenticket.tasks.pixels import PixelsTask, pixel_task_names
from goldenticket.tasks.robomimic import RobomimicTask


def get_task(task: str | Callable, max_steps: int | None = None, success: Callable | str | None = None
             ) -> MetaWorldTask | GymTask | LeRobotEnvTask | RobomimicTask:
    """A built-in task by name (Meta-World's, robomimic's, LeRobot's simulated envs), or a Gymnasium env
    from a factory (a callable or an import string `pkg.mod:factory`) with an optional success predicate;
    unknown names are a UserError listing a few valid ones."""
    if max_steps is not None and max_steps < 1:
        raise OptionError(f"max_steps must be >= 1, got {max_steps}", "max_steps")
    limit = {} if max_steps is None else {"max_steps": max_steps}
    if callable(task) or is_import_string(task):
        return GymTask(task, success=success, **limit)
    if success is not None:
        raise OptionError(f"success applies to Gymnasium tasks; {task!r} has its own success signal",
                          "success")
    if task.startswith("robomimic/"):
        return RobomimicTask(task, **limit)
    if is_lerobot_env_task(task):
        return LeRobotEnvTask(task, **limit)
    if task in pixel_task_names():
        return PixelsTask(task, **limit)
    if task not in task_names():
        hint = ", ".join(n for n in task_names() if "pick" in n or "reach" in n)
        raise UserError(f"unknown task {task!r}; tasks look like: {hint} (metaworld-pixels/<env-name> "
                        "seen through a camera; LeRobot's envs libero/<suite>/<task id>, "
                        "libero-listed/<suite>/<task id>, pusht, aloha/insertion, aloha/transfer-cube; "
                        "robomimic/lift, can, square, transport; "
                        "or package.module:factory for a Gymnasium env of yours)")
    return MetaWorldTask(task, **limit)

"""Seeded environments: the same integer seed always gives the same initial state."""

from goldenticket.objectives import OBJECTIVES
from goldenticket.seeds import SEED_SETS, seeds_in
from goldenticket.tasks.base import Env, Task

# isort: off
# Each task family registers itself with the registry when imported; the unknown-task line offers them
# in this order.
from goldenticket.tasks.gym import GymTask
from goldenticket.tasks.metaworld import MetaWorldTask, task_names
from goldenticket.tasks import pixels, lerobot_envs, robomimic  # noqa: F401
# isort: on
from goldenticket.tasks.registry import get_task

__all__ = ["OBJECTIVES", "SEED_SETS", "Env", "GymTask", "MetaWorldTask", "Task", "get_task", "seeds_in",
           "task_names"]

"""Seeded environments: the same integer seed always gives the same initial state."""

from goldenticket.objectives import OBJECTIVES
from goldenticket.seeds import SEED_SETS, seeds_in
from goldenticket.tasks.base import Env, Task
from goldenticket.tasks.gym import GymTask
from goldenticket.tasks.metaworld import MetaWorldTask, task_names
from goldenticket.tasks.registry import get_task

__all__ = ["OBJECTIVES", "SEED_SETS", "Env", "GymTask", "MetaWorldTask", "Task", "get_task", "seeds_in",
           "task_names"]

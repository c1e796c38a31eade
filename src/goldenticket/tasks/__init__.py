"""Seeded environments: the same integer seed always gives the same initial state."""

from goldenticket.tasks.base import OBJECTIVES, SEED_SETS, Env, Task, seeds_in
from goldenticket.tasks.gym import GymTask
from goldenticket.tasks.metaworld import MetaWorldTask, task_names
from goldenticket.tasks.registry import get_task

__all__ = ["OBJECTIVES", "SEED_SETS", "Env", "GymTask", "MetaWorldTask", "Task", "get_task", "seeds_in",
           "task_names"]

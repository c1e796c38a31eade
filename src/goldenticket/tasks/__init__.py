"""Seeded environments: the same integer seed always gives the same initial state."""

from goldenticket.tasks.base import OBJECTIVES, SEED_SETS, Env, Task, seeds_in
from goldenticket.tasks.metaworld import MetaWorldTask, get_task, task_names

__all__ = ["OBJECTIVES", "SEED_SETS", "Env", "MetaWorldTask", "Task", "get_task", "seeds_in",
           "task_names"]

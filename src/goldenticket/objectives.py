"""Objectives: an episode's return from its success, length and progress."""

from __future__ import annotations

from collections.abc import Callable


def _discounted(success: bool, length: int, max_steps: int, progress: float, gamma: float = 0.99) -> float:
    return float(success) * gamma ** (length - 1)


PROGRESS_WEIGHT = 0.01  # below 1/n for n <= 100 episodes: a tie-breaker, never outweighs one success

# Episode return from (success, length, max_steps, progress); higher is better for every objective.
# progress: how far a failed episode got, in [0, 1] (Env.progress; 1 on success, 0 if unknown).
OBJECTIVES: dict[str, Callable[[bool, int, int, float], float]] = {
    "success": lambda success, length, max_steps, progress: float(success),
    "success-progress": lambda success, length, max_steps, progress: success + PROGRESS_WEIGHT * progress,
    "discounted-success": _discounted,
    "length": lambda success, length, max_steps, progress: -length / max_steps,
    "speed": lambda success, length, max_steps, progress: (1 - length / max_steps) if success else 0.0,
}
PROGRESS_OBJECTIVES = frozenset({"success-progress"})  # the objectives that read Env.progress()
FRONT_OBJECTIVES = tuple(o for o in OBJECTIVES if o not in PROGRESS_OBJECTIVES)  # from success, length

"""What the search driver and every optimizer speak: a `Query` (a ticket on some seeds) and the
ask/tell `Optimizer`. Protocol: call `ask()`, evaluate every query it returned, then `tell()` all of
them, in order, before asking again."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True, eq=False)
class Query:
    """Roll `ticket` out once on each of `seeds`. The ticket is stored as a read-only float32 copy."""

    ticket: np.ndarray
    seeds: tuple[int, ...]

    def __post_init__(self) -> None:
        ticket = np.array(self.ticket, dtype=np.float32)
        ticket.flags.writeable = False
        object.__setattr__(self, "ticket", ticket)
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))


class Optimizer(Protocol):
    """What the search driver needs; `seeds` are the search seeds the optimizer rolls out on."""

    seeds: tuple[int, ...]

    def ask(self) -> list[Query]:
        """Queries to evaluate next; [] means the optimizer is finished."""

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        """Report `returns[i]`, the per-seed returns of `queries[i]`, for the whole last ask."""

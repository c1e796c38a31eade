"""Racing across a whole search: any optimizer's tickets spend episodes only while they can still
be the best.

Each ticket an optimizer asks for runs on the search seeds block by block, every ticket on the
same blocks in the same order, so any two tickets compare on the seeds both ran (paired). After
each block a ticket stops if a one-sided sign test on those seeds says it is worse than the
incumbent, the best ticket so far that ran on every search seed, at p < `alpha`. The optimizer is
then told each ticket's returns on the seeds it ran, as it would be told a full score. Pure, like
the optimizers: no I/O and no random draws of its own.
"""

from __future__ import annotations

import numpy as np

from goldenticket.errors import UserError
from goldenticket.stats import sign_test
from goldenticket.ticket_search.optimizers import Optimizer, Query

RACE_BLOCK = 5  # search seeds a raced ticket runs on between two tests (a run's `race` setting)


class Raced:
    """`inner`'s tickets raced against the incumbent on blocks of `block` search seeds."""

    def __init__(self, inner: Optimizer, block: int, alpha: float):
        if not 1 <= block <= len(inner.seeds):
            raise UserError(f"race block must be in 1..{len(inner.seeds)} search seeds, got {block}")
        if not 0 < alpha < 1:
            raise UserError(f"race level must be in (0, 1), got {alpha}")
        self.inner, self.seeds, self.alpha = inner, inner.seeds, alpha
        self.blocks = [self.seeds[i : i + block] for i in range(0, len(self.seeds), block)]
        self.incumbent: np.ndarray | None = None  # its returns on every search seed, in seed order
        self._batch: list[Query] = []
        self._runs: list[list[np.ndarray]] = []  # per ticket of the batch: its returns block by block
        self._alive: list[int] = []  # batch indices still racing; empty between batches

    def ask(self) -> list[Query]:
        if not self._alive:
            self._batch = self.inner.ask()
            self._runs, self._alive = [[] for _ in self._batch], list(range(len(self._batch)))
        block = self.blocks[len(self._runs[self._alive[0]])] if self._alive else ()
        return [Query(self._batch[i].ticket, block) for i in self._alive]

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        for i, r in zip(self._alive, returns, strict=True):
            self._runs[i].append(np.asarray(r, dtype=np.float64))
        if len(self._runs[self._alive[0]]) == len(self.blocks):
            self._alive = []
        else:
            self._alive = [i for i in self._alive if not self._beaten(np.concatenate(self._runs[i]))]
        if not self._alive:
            self._finish()

    def _beaten(self, returns: np.ndarray) -> bool:
        """Whether the incumbent is better on the seeds these `returns` ran, at p < alpha."""
        if self.incumbent is None:
            return False
        theirs = self.incumbent[: len(returns)]
        return sign_test(int(np.sum(theirs > returns)), int(np.sum(returns > theirs))) < self.alpha

    def _finish(self) -> None:
        """Tell the inner optimizer the batch's returns; the best full run may become the incumbent."""
        scored = [np.concatenate(runs) for runs in self._runs]
        for returns in scored:
            full = len(returns) == len(self.seeds)
            if full and (self.incumbent is None or returns.mean() > self.incumbent.mean()):
                self.incumbent = returns
        self.inner.tell(self._batch, scored)

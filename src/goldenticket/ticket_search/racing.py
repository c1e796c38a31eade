"""Racing across a whole search: any optimizer's tickets spend episodes only while they can still
be the best.

Each batch of tickets an optimizer asks for runs on the search seeds block by block, every ticket
on the same blocks in the same order, so any two tickets compare on the seeds both ran (paired).
After each block some tickets stop:
- `Raced`: a ticket stops if a one-sided sign test on those seeds says it is worse than the
  incumbent, the best ticket so far that ran on every search seed, at p < `alpha`;
- `Halved` (sequential halving): only the better half of the batch's tickets still running, by
  mean return on the seeds they all ran, goes on to the next block.
The optimizer is then told each ticket's returns on the seeds it ran, as it would be told a full
score. Pure, like the optimizers: no I/O and no random draws of their own.
"""

from __future__ import annotations

import numpy as np

from goldenticket.errors import UserError
from goldenticket.stats import sign_test
from goldenticket.ticket_search.optimizers import Optimizer, Query

RACE_BLOCK = 5  # search seeds a raced ticket runs on between two tests (a run's `race` and `halving`)


class _BlockRace:
    """`inner`'s batches run block by block over its search seeds; `_survivors` says which of the
    batch's tickets still running go on after each block."""

    def __init__(self, inner: Optimizer, block: int):
        if not 1 <= block <= len(inner.seeds):
            raise UserError(f"race block must be in 1..{len(inner.seeds)} search seeds, got {block}")
        self.inner, self.seeds = inner, inner.seeds
        self.blocks = [self.seeds[i : i + block] for i in range(0, len(self.seeds), block)]
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
            self._alive = self._survivors({i: np.concatenate(self._runs[i]) for i in self._alive})
        if not self._alive:
            self._finish([np.concatenate(runs) for runs in self._runs])

    def _survivors(self, running: dict[int, np.ndarray]) -> list[int]:
        raise NotImplementedError

    def _finish(self, scored: list[np.ndarray]) -> None:
        """Tell the inner optimizer the batch's returns."""
        self.inner.tell(self._batch, scored)


class Raced(_BlockRace):
    """`inner`'s tickets raced against the incumbent on blocks of `block` search seeds."""

    def __init__(self, inner: Optimizer, block: int, alpha: float):
        super().__init__(inner, block)
        if not 0 < alpha < 1:
            raise UserError(f"race level must be in (0, 1), got {alpha}")
        self.alpha = alpha
        self.incumbent: np.ndarray | None = None  # its returns on every search seed, in seed order

    def _survivors(self, running: dict[int, np.ndarray]) -> list[int]:
        return [i for i, returns in running.items() if not self._beaten(returns)]

    def _beaten(self, returns: np.ndarray) -> bool:
        """Whether the incumbent is better on the seeds these `returns` ran, at p < alpha."""
        if self.incumbent is None:
            return False
        theirs = self.incumbent[: len(returns)]
        return sign_test(int(np.sum(theirs > returns)), int(np.sum(returns > theirs))) < self.alpha

    def _finish(self, scored: list[np.ndarray]) -> None:
        """The best full run may become the incumbent; then the inner optimizer is told."""
        for returns in scored:
            full = len(returns) == len(self.seeds)
            if full and (self.incumbent is None or returns.mean() > self.incumbent.mean()):
                self.incumbent = returns
        super()._finish(scored)


class Halved(_BlockRace):
    """`inner`'s batches raced by sequential halving on blocks of `block` search seeds: after each
    block the better half (at least one) of the tickets still running goes on, ties to the one
    asked first; the last ones run every block."""

    def _survivors(self, running: dict[int, np.ndarray]) -> list[int]:
        ranked = sorted(running, key=lambda i: -running[i].mean())  # stable: ties keep the ask order
        return sorted(ranked[: max(1, len(running) // 2)])

"""Races: candidates run round by round, and after each round only some go on.

`Race` is the one mechanism behind every race in goldenticket: the search's (`Raced`, `Halved`,
and CEM's own, `optimizers.CEMRacing` and `CEMBounds`), validation by halving
(`job.stages.validate`) and a real-robot session's race by successive elimination
(`session.race`). Each round every candidate still in runs (a block of seeds, a round of
episodes), the race keeps each one's results round by round, and a cut says who goes on:
- `better_half` (sequential halving): the better half (at least one) by score, ties to the
  candidate first in order (`Halved`, cem-racing, validation);
- `Raced`: those a one-sided sign test on the seeds they ran does not find worse than the
  incumbent, the best ticket so far that ran on every search seed, at p < `alpha`;
- cem-bounds: those whose Hoeffding upper bound still reaches the elites' lower bounds;
- a session: those that do not trail the leader (`session.race.trails`).

In the search, each batch of tickets an optimizer asks for runs on the search seeds block by
block, every ticket on the same blocks in the same order, so any two tickets compare on the seeds
both ran (paired); once the race is over, the optimizer is told each ticket's returns on the seeds
it ran, as it would be told a full score. Pure, like the optimizers: no I/O and no random draws of
their own.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

import numpy as np

from goldenticket.errors import UserError
from goldenticket.stats import sign_test
from goldenticket.ticket_search.protocol import Optimizer, Query

RACE_BLOCK = 5  # search seeds a raced ticket runs on between two tests (a run's `race` and `halving`)


class Race:
    """`candidates` (numbered from 0) raced round by round. Each round every candidate still in
    (`alive`, in their order) runs, and `record` keeps its result; then, unless that was the last of
    `rounds` (None: no last), `cut(race)` says who goes on. The race is over after its last round or
    once nobody is left. `score(results)` ranks a candidate by its results so far, round by round."""

    def __init__(self, candidates: int, cut: Callable[[Race], Iterable[int]],
                 score: Callable[[list], float], rounds: int | None = None):
        self.cut, self.rounds, self._score = cut, rounds, score
        self.results: list[list] = [[] for _ in range(candidates)]
        self.alive = list(range(candidates))
        self.round = 0

    @property
    def over(self) -> bool:
        return not self.alive or self.round == self.rounds

    def record(self, results: Sequence) -> None:
        """This round's result of each candidate still in, in their order; then the cut."""
        for i, result in zip(self.alive, results, strict=True):
            self.results[i].append(result)
        self.round += 1
        if not self.over:
            self.alive = sorted(self.cut(self))

    def score(self, candidate: int) -> float:
        return self._score(self.results[candidate])

    def ranked(self) -> list[int]:
        """The candidates still in, best score first; ties to the one first in order."""
        return sorted(self.alive, key=lambda i: -self.score(i))


def better_half(race: Race) -> list[int]:
    """Sequential halving's cut: the better half (at least one) of the candidates still in."""
    return race.ranked()[: max(1, len(race.alive) // 2)]


def halving_sizes(candidates: int, keep: int, rounds: int) -> list[int]:
    """How many of `candidates` run each round of a race cut by `better_half` that ends, within at
    most `rounds` rounds, once that half would not be more than the `keep` to choose: [10, 5] for
    10, 3 and 4."""
    sizes = [candidates]
    while len(sizes) < rounds and sizes[-1] // 2 > keep:
        sizes.append(sizes[-1] // 2)
    return sizes


def in_blocks(seeds: Sequence[int], size: int) -> list:
    """`seeds` cut in order into blocks of `size` (the last one shorter where they do not divide)."""
    return [seeds[i : i + size] for i in range(0, len(seeds), size)]


class TicketRace(Race):
    """`tickets` raced on `blocks` of seeds: round r runs every ticket still in on block r."""

    def __init__(self, tickets: Sequence[np.ndarray], blocks: list, cut: Callable[[Race], Iterable[int]],
                 score: Callable[[list], float]):
        super().__init__(len(tickets), cut, score, len(blocks))
        self.tickets, self.blocks = tickets, blocks

    def queries(self) -> list[Query]:
        """The next round's queries; [] once the race is over."""
        return [] if self.over else [Query(self.tickets[i], self.blocks[self.round]) for i in self.alive]


def _mean_return(blocks: list[np.ndarray]) -> float:
    """A raced ticket's mean return over every seed it ran."""
    return np.concatenate(blocks).mean()


class _RacedBatches:
    """`inner`'s batches raced (`TicketRace`) on blocks of `block` of its search seeds; `_cut` says
    who goes on after each block."""

    def __init__(self, inner: Optimizer, block: int):
        if not 1 <= block <= len(inner.seeds):
            raise UserError(f"race block must be in 1..{len(inner.seeds)} search seeds, got {block}")
        self.inner, self.seeds = inner, inner.seeds
        self.blocks = in_blocks(self.seeds, block)
        self._batch: list[Query] = []
        self._race: TicketRace | None = None

    def ask(self) -> list[Query]:
        if self._race is None or self._race.over:
            self._batch = self.inner.ask()
            self._race = TicketRace([q.ticket for q in self._batch], self.blocks, self._cut, _mean_return)
        return self._race.queries()

    def tell(self, queries: list[Query], returns: list[np.ndarray]) -> None:
        self._race.record([np.asarray(r, dtype=np.float64) for r in returns])
        if self._race.over:
            self._finish([np.concatenate(blocks) for blocks in self._race.results])

    def _cut(self, race: Race) -> list[int]:
        raise NotImplementedError

    def _finish(self, scored: list[np.ndarray]) -> None:
        """Tell the inner optimizer the batch's returns."""
        self.inner.tell(self._batch, scored)


class Raced(_RacedBatches):
    """`inner`'s tickets raced against the incumbent on blocks of `block` search seeds."""

    def __init__(self, inner: Optimizer, block: int, alpha: float):
        super().__init__(inner, block)
        if not 0 < alpha < 1:
            raise UserError(f"race level must be in (0, 1), got {alpha}")
        self.alpha = alpha
        self.incumbent: np.ndarray | None = None  # its returns on every search seed, in seed order

    def _cut(self, race: Race) -> list[int]:
        return [i for i in race.alive if not self._beaten(np.concatenate(race.results[i]))]

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


class Halved(_RacedBatches):
    """`inner`'s batches raced by sequential halving on blocks of `block` search seeds: after each
    block the better half (at least one) of the tickets still running goes on, ties to the one
    asked first; the last ones run every block."""

    def _cut(self, race: Race) -> list[int]:
        return better_half(race)

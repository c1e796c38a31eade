"""Search driver: run an ask/tell optimizer against an episode evaluator within a budget.

Budget and ticket-cap truncation: the optimizer only ever hears about complete asks. When the
next ask does not fit (its episodes exceed the budget left, or its new tickets exceed
`max_tickets`), the driver evaluates the longest prefix of whole queries that fits, records
those episodes in the result, tells the optimizer nothing and stops. Telling a partial ask
would corrupt the optimizers' invariants: CEM would refit on a few arbitrary candidates, racing
would halve an incomplete tier, ZOS would move its pivot after seeing only some candidates.
The optimizer is therefore left as after its last complete tell (plus one un-told ask), and a
query is never run on only some of its seeds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from goldenticket.errors import UserError
from goldenticket.ticket_search.protocol import Optimizer, Query


@dataclass
class EpisodeOutcome:
    """What `evaluate` returns per query: one return and one success flag per seed, in order."""

    returns: np.ndarray
    successes: np.ndarray


@dataclass
class Candidate:
    """One distinct ticket and every episode measured for it, in evaluation order."""

    ticket: np.ndarray
    seeds: list[int] = field(default_factory=list)
    returns: list[float] = field(default_factory=list)
    successes: list[bool] = field(default_factory=list)

    @property
    def n(self) -> int:
        """Number of episodes run with this ticket."""
        return len(self.returns)

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))


@dataclass
class SearchResult:
    """Every evaluated ticket (first-seen order), the episodes spent and why the search stopped:
    "budget", "optimizer finished", "k perfect tickets" or "ticket cap"."""

    candidates: list[Candidate]
    episodes_used: int
    stopped_because: str

    def top(self, k: int, min_episodes: int | None = None, shrink: int = 0) -> list[Candidate]:
        """The k best candidates with at least `min_episodes` episodes, by mean return; with `shrink`,
        by their mean return as if `shrink` more episodes had scored the search's mean return, so that
        a ticket seen on few seeds ranks by less than its own mean.

        Ties go to the candidate with more episodes, then to the one seen first.
        """
        pool = [c for c in self.candidates if min_episodes is None or c.n >= min_episodes]
        if not shrink:
            return sorted(pool, key=lambda c: (-c.mean_return, -c.n))[:k]
        prior = shrink * float(np.mean([r for c in self.candidates for r in c.returns]))
        return sorted(pool, key=lambda c: (-(sum(c.returns) + prior) / (c.n + shrink), -c.n))[:k]


def run_search(optimizer: Optimizer, evaluate: Callable[[list[Query]], list[EpisodeOutcome]],
               *, budget: int, max_tickets: int | None = None,
               stop_after_perfect: int | None = None,
               on_batch: Callable[[int], None] | None = None) -> SearchResult:
    """Loop ask -> evaluate -> tell until a stop condition; never spend more than `budget` episodes.

    A ticket evaluated again (same bytes) accumulates into its existing Candidate. `max_tickets`
    caps the number of distinct tickets. `stop_after_perfect` stops once that many candidates have
    run on every search seed of the optimizer and succeeded in every episode.
    `on_batch(episodes)` is called after each evaluation. See the module docstring for how a
    batch that does not fit is truncated.
    """
    _check_limits(budget, max_tickets, stop_after_perfect)
    found: dict[bytes, Candidate] = {}
    used = 0
    while True:
        queries = optimizer.ask()
        if not queries:
            return SearchResult(list(found.values()), used, "optimizer finished")
        fit, cut = _fitting_prefix(queries, found, budget - used, max_tickets)
        batch = queries[:fit]
        outcomes = evaluate(batch) if batch else []
        used += _record(found, batch, outcomes)
        if batch and on_batch is not None:
            on_batch(sum(len(q.seeds) for q in batch))
        if cut is None:
            optimizer.tell(batch, [np.asarray(o.returns, dtype=np.float64) for o in outcomes])
        perfect = stop_after_perfect is not None and \
            _count_perfect(found, optimizer.seeds) >= stop_after_perfect
        if perfect or cut is not None:
            return SearchResult(list(found.values()), used, "k perfect tickets" if perfect else cut)


def _check_limits(budget: int, max_tickets: int | None, stop_after_perfect: int | None) -> None:
    if budget <= 0:
        raise UserError(f"budget must be at least 1 episode, got {budget}")
    if max_tickets is not None and max_tickets < 1:
        raise UserError(f"max_tickets must be at least 1, got {max_tickets}")
    if stop_after_perfect is not None and stop_after_perfect < 1:
        raise UserError(f"stop_after_perfect must be at least 1, got {stop_after_perfect}")


def _fitting_prefix(queries: list[Query], found: dict[bytes, Candidate], room: int,
                    max_tickets: int | None) -> tuple[int, str | None]:
    """How many leading queries fit the episode room and ticket cap, and which limit cut (if any)."""
    episodes, new = 0, set()
    for i, query in enumerate(queries):
        episodes += len(query.seeds)
        if episodes > room:
            return i, "budget"
        key = query.ticket.tobytes()
        if key not in found:
            new.add(key)
        if max_tickets is not None and len(found) + len(new) > max_tickets:
            return i, "ticket cap"
    return len(queries), None


def _record(found: dict[bytes, Candidate], batch: list[Query],
            outcomes: list[EpisodeOutcome]) -> int:
    """Add every episode of `batch` to its Candidate; returns the number of episodes."""
    if len(outcomes) != len(batch):
        raise ValueError(f"evaluate returned {len(outcomes)} outcomes for {len(batch)} queries")
    episodes = 0
    for query, outcome in zip(batch, outcomes, strict=True):
        n = len(query.seeds)
        if len(outcome.returns) != n or len(outcome.successes) != n:
            raise ValueError(f"evaluate must return one return and success per seed ({n})")
        cand = found.setdefault(query.ticket.tobytes(), Candidate(query.ticket))
        cand.seeds += query.seeds
        cand.returns += [float(r) for r in outcome.returns]
        cand.successes += [bool(s) for s in outcome.successes]
        episodes += n
    return episodes


def _count_perfect(found: dict[bytes, Candidate], seeds: tuple[int, ...]) -> int:
    """Candidates run on every search seed that succeeded in every episode (any objective)."""
    needed = set(seeds)
    return sum(needed <= set(c.seeds) and all(c.successes) for c in found.values())

"""From the driver's queries to episodes: the adapter between `run_search` and whatever runs
episodes (the job's Evaluator, a cluster, a person), with no engine of its own."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from goldenticket.ticket_search.driver import EpisodeOutcome
from goldenticket.ticket_search.protocol import Query

# run_tickets(jobs, task): each job a (ticket, seeds) pair; returns, per job, its episodes in seed
# order, each with `.ret` and `.success`.
RunTickets = Callable[[list[tuple[np.ndarray, list[int]]], str | None], Sequence[Sequence]]


def query_evaluator(run_tickets: RunTickets, expand: Callable = lambda searched: searched,
                    where: Callable[[int], tuple[str | None, int]] = lambda key: (None, key)):
    """The driver's evaluate(): each query's episodes through `run_tickets`; `expand` turns a
    searched array into the full ticket, `where` a query's seed key into the (task, seed) it runs on
    (a multi-task search; default: the runner's task, the seed itself)."""
    def evaluate(queries: list[Query]) -> list[EpisodeOutcome]:
        tickets = [expand(q.ticket) for q in queries]
        returns = [np.zeros(len(q.seeds)) for q in queries]
        successes = [np.zeros(len(q.seeds), dtype=bool) for q in queries]
        by_task: dict = {}  # task -> query index -> [(position in query, seed)]
        for i, q in enumerate(queries):
            for position, key in enumerate(q.seeds):
                task, seed = where(key)
                by_task.setdefault(task, {}).setdefault(i, []).append((position, seed))
        for task, slots in by_task.items():
            jobs = [(tickets[i], [seed for _, seed in pairs]) for i, pairs in slots.items()]
            for (i, pairs), results in zip(slots.items(), run_tickets(jobs, task), strict=True):
                for (position, _), r in zip(pairs, results, strict=True):
                    returns[i][position], successes[i][position] = r.ret, r.success
        return [EpisodeOutcome(r, s) for r, s in zip(returns, successes, strict=True)]
    return evaluate

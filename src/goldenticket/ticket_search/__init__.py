"""Black-box search for golden tickets: pure ask/tell optimizers, the budgeted driver and its adapter
to whatever runs episodes."""

from goldenticket.ticket_search.adapter import query_evaluator
from goldenticket.ticket_search.driver import (
    Candidate,
    EpisodeOutcome,
    SearchResult,
    run_search,
)
from goldenticket.ticket_search.optimizers import (
    CEM,
    CMAES,
    OPTIMIZERS,
    CEMRacing,
    Optimizer,
    Query,
    RandomSearch,
    ZerothOrder,
    make_optimizer,
)
from goldenticket.ticket_search.racing import RACE_BLOCK, Halved, Raced

__all__ = [
    "CEM",
    "CMAES",
    "OPTIMIZERS",
    "CEMRacing",
    "Candidate",
    "EpisodeOutcome",
    "Halved",
    "Optimizer",
    "Query",
    "RACE_BLOCK",
    "Raced",
    "RandomSearch",
    "SearchResult",
    "ZerothOrder",
    "make_optimizer",
    "query_evaluator",
    "run_search",
]

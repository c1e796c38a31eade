"""The job's results: frozen dataclasses of verdict rows and tickets, turned into JSON only where
a file or the public API is written (`to_dict`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from goldenticket.evaluation import ZERO_MARK, MultitaskVerdict, VerdictRow, p_value_note, to_dicts
from goldenticket.tickets import ZERO_SOURCE, Ticket


def arm_rows(base: VerdictRow, zero: VerdictRow, tickets: dict[str, VerdictRow]) -> dict[str, VerdictRow]:
    """Verdict rows as people read them: base, zero ticket, then each ticket (`tickets` by id, or by
    `FoundTicket.label`)."""
    return {"base": base, "zero ticket": zero} | {f"ticket {t}": row for t, row in tickets.items()}


def to_run(best: float, zero: float, base: float, golden: bool) -> str:
    """What to run after a verdict, given the held-out success rates of the best ticket, the zero
    ticket and the base, and whether the best is golden; never an arm below the base there: "best"
    if it is golden, else whichever of "best" and "zero" succeeded more often (the best on a tie;
    where the zero ticket was judged among the tickets it is the best on a tie) if that is more
    often than the base, else "base"."""
    if golden:
        return "best"
    ahead, rate = ("zero", zero) if zero > best else ("best", best)
    return ahead if rate > base else "base"


DELIVERED = {"best": "ticket", "zero": "zero ticket", "base": "base"}  # summary.json's `deliver`


@dataclass(frozen=True)
class FoundTicket:
    """A ticket the job judged: its id and file, its held-out verdict, its mean return on the search
    and validation seeds (None: not scored there), if not the search's, where it came from, and the
    ticket itself (noise and metadata, as saved)."""

    id: str
    path: str
    search_score: float | None
    heldout: VerdictRow
    validation_score: float | None = None
    source: str | None = None  # ZERO_SOURCE or "given: <ticket>"
    ticket: Ticket | None = field(default=None, repr=False, compare=False)

    @property
    def name(self) -> str:
        """The id, and what it is when it is the zero ticket."""
        return self.id + (" (the zero ticket, w = 0)" if self.source == ZERO_SOURCE else "")

    @property
    def label(self) -> str:
        """Its row's label in the verdict table (`arm_rows`)."""
        return self.id + (ZERO_MARK if self.source == ZERO_SOURCE else "")

    def to_dict(self) -> dict:
        validation = {k: v for k, v in (("validation_score", self.validation_score), ("source", self.source))
                      if v is not None}
        return self.heldout.to_dict() | validation | {"ticket_id": self.id, "ticket_path": self.path,
                                                      "search_score": self.search_score}


@dataclass(frozen=True)
class SearchRun:
    """What a summary says of the search: policy, method, seed, episodes spent, why it stopped, and
    the first and last held-out seed of the verdict."""

    policy: str
    method: str
    seed: int
    search_episodes: int
    stopped_because: str
    heldout_seeds: tuple[int, int]

    def to_dict(self) -> dict:
        return {"policy": self.policy, "method": self.method, "seed": self.seed,
                "search_episodes": self.search_episodes, "stopped_because": self.stopped_because,
                "heldout_seeds": list(self.heldout_seeds)}


@dataclass(frozen=True)
class FrontArm:
    """An arm judged with a Pareto front: its held-out row, its score per objective there, and the
    front ticket's file (None for base and zero)."""

    row: VerdictRow
    scores: dict[str, float]
    ticket_path: str | None = None

    def to_dict(self) -> dict:
        path = {} if self.ticket_path is None else {"ticket_path": self.ticket_path}
        return self.row.to_dict() | {"scores": self.scores} | path


@dataclass(frozen=True)
class ParetoFront:
    """The tickets no other ticket beats on both objectives: every scored ticket's search scores
    (`search`: (ticket id, scores, on the front)), and base, zero and the front judged on held-out
    seeds (`heldout`)."""

    objectives: tuple[str, str]
    heldout_seeds: tuple[int, int]
    search: tuple[tuple[str, dict[str, float], bool], ...]
    heldout: dict[str, FrontArm]

    @property
    def tickets(self) -> tuple[str, ...]:
        return tuple(label for label in self.heldout if label not in ("base", "zero"))

    def to_dict(self) -> dict:
        """front.json."""
        search = [{"ticket_id": t, "scores": scores, "front": front} for t, scores, front in self.search]
        return {"objectives": list(self.objectives), "heldout_seeds": list(self.heldout_seeds),
                "search": search, "heldout": {label: arm.to_dict() for label, arm in self.heldout.items()}}


@dataclass(frozen=True)
class Summary:
    """The job's result on one task: base, zero ticket and the tickets judged (best first, p-values
    Holm-adjusted over them), and the Pareto front when there is one."""

    task: str
    run: SearchRun
    base: VerdictRow
    zero: VerdictRow
    tickets: tuple[FoundTicket, ...]
    front: ParetoFront | None = None

    @property
    def best(self) -> FoundTicket:
        return self.tickets[0]

    @property
    def deliver(self) -> str:
        """What the job delivers (`to_run`): "ticket" (the best), "zero ticket" (also where the best
        is the zero ticket) or "base"."""
        best = self.best.heldout
        rates = (best.rate.success_rate, self.zero.rate.success_rate, self.base.rate.success_rate)
        run = to_run(*rates, best.golden)
        return DELIVERED["zero" if run == "best" and self.best.source == ZERO_SOURCE else run]

    @property
    def p_value_note(self) -> str:
        return p_value_note(len(self.tickets))

    def rows(self) -> dict[str, VerdictRow]:
        """The verdict rows as people read them (`arm_rows`)."""
        return arm_rows(self.base, self.zero, {t.label: t.heldout for t in self.tickets})

    def to_dict(self) -> dict:
        """summary.json."""
        front = {} if self.front is None else {"front": list(self.front.tickets)}
        return {"task": self.task} | self.run.to_dict() | {
            "base": self.base.to_dict(), "zero": self.zero.to_dict(), "best": self.best.to_dict(),
            "deliver": self.deliver, "tickets": [t.to_dict() for t in self.tickets],
            "p_value_note": self.p_value_note} | front


@dataclass(frozen=True)
class TransferCell:
    """One ticket on one task: success, gain over the task's base, p vs base Holm-adjusted over the
    tickets on that task (None: the base itself), and whether that p is below ALPHA."""

    success_rate: float
    gain: float
    p_vs_base: float | None
    significant: bool

    def to_dict(self) -> dict:
        return {"success_rate": self.success_rate, "gain": self.gain, "p_vs_base": self.p_vs_base,
                "significant": self.significant}


@dataclass(frozen=True)
class Cover:
    """The greedy cover: its tickets, the other tickets the switching table uses, and per task the
    ticket to run ("base": none) with its cell."""

    tickets: tuple[str, ...]
    fallbacks: tuple[str, ...]
    table: dict[str, tuple[str, TransferCell]]

    def to_dict(self) -> dict:
        return {"tickets": list(self.tickets), "fallbacks": list(self.fallbacks),
                "table": {task: {"use": use} | cell.to_dict() for task, (use, cell) in self.table.items()}}


@dataclass(frozen=True)
class TransferStudy:
    """Every ticket (with the tasks it was found on) on every task's held-out seeds: base and zero
    rows per task, a cell per (ticket, task), and the greedy cover."""

    policy: str
    heldout_seeds: tuple[int, int]
    tickets: dict[str, list[str]]
    baselines: dict[str, dict[str, VerdictRow]]  # task -> "base" and "zero" rows
    cells: dict[str, dict[str, TransferCell]]  # ticket -> task -> cell
    cover: Cover

    @property
    def tasks(self) -> list[str]:
        return list(self.baselines)

    def to_dict(self) -> dict:
        """transfer.json."""
        cells = {t: {task: cell.to_dict() for task, cell in row.items()} for t, row in self.cells.items()}
        return {"tasks": self.tasks, "tickets": self.tickets,
                "baselines": {task: to_dicts(rows) for task, rows in self.baselines.items()}, "cells": cells,
                "cover": self.cover.to_dict(), "policy": self.policy,
                "heldout_seeds": list(self.heldout_seeds)}


@dataclass(frozen=True)
class MultitaskSummary:
    """The job's result on several tasks: the verdict per task and on average, the search, and each
    judged ticket's validation score (task-averaged mean return; empty without validation)."""

    verdict: MultitaskVerdict
    run: SearchRun
    validation: dict[str, float] = field(default_factory=dict)

    @property
    def p_value_note(self) -> str:
        return p_value_note(len(self.verdict.tickets))

    def to_dict(self) -> dict:
        """summary.json."""
        scores = {"validation_scores": self.validation} if self.validation else {}
        return self.verdict.to_dict() | self.run.to_dict() | scores | {"p_value_note": self.p_value_note}

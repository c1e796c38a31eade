"""The job's results: frozen dataclasses of verdict rows and tickets, turned into JSON only where
a file or the public API is written (`to_dict`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

from goldenticket.evaluation import (
    ALPHA,
    BASE,
    ZERO,
    Arm,
    Judged,
    MultitaskVerdict,
    VerdictRow,
    p_value_note,
    to_dicts,
)
from goldenticket.stats import Rate, paired_exact_test
from goldenticket.tickets import ZERO_SOURCE, Ticket


@dataclass(frozen=True)
class VerdictTable:
    """A verdict as people read it, each arm once: the base, the zero ticket, then the candidates by
    label (tickets, best first; a mixture). Where the zero ticket was judged as one of the tickets
    (`zero_judged_as`: its id), its row is that ticket's, its p vs base Holm-adjusted over the tickets
    like theirs (`zero_unadjusted`: before the adjustment)."""

    base: VerdictRow
    zero: VerdictRow
    candidates: dict[str, VerdictRow]
    zero_judged_as: str | None = None
    zero_unadjusted: float | None = None

    def rows(self) -> dict[str, VerdictRow]:
        """Every row by label, in table order."""
        return {BASE.label: self.base, ZERO.label: self.zero} | self.candidates

    @property
    def adjusted_over(self) -> int:
        """The number of candidates the p-values are Holm-adjusted over."""
        return len(self.candidates) + (self.zero_judged_as is not None)


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
        return self.id + (" (the zero ticket, w = 0)" if self.is_zero else "")

    @property
    def is_zero(self) -> bool:
        """Whether it is the zero ticket."""
        return self.source == ZERO_SOURCE

    @property
    def label(self) -> str:
        """Its row's label in the verdict table (`Summary.table`)."""
        return ZERO.label if self.is_zero else Arm.ticket(self.id).label

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
    heldout: dict[Arm, FrontArm]

    @property
    def tickets(self) -> tuple[str, ...]:
        return tuple(arm.key for arm in self.heldout if arm.candidate)

    def to_dict(self) -> dict:
        """front.json."""
        search = [{"ticket_id": t, "scores": scores, "front": front} for t, scores, front in self.search]
        return {"objectives": list(self.objectives), "heldout_seeds": list(self.heldout_seeds),
                "search": search,
                "heldout": {arm.key: front.to_dict() for arm, front in self.heldout.items()}}


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
        return DELIVERED["zero" if run == "best" and self.best.is_zero else run]

    @property
    def p_value_note(self) -> str:
        return p_value_note(len(self.tickets))

    def table(self) -> VerdictTable:
        """The verdict as people read it: the zero ticket once, as the ticket it was judged as where it was
        one of them."""
        candidates = {t.label: t.heldout for t in self.tickets if not t.is_zero}
        judged = next((t for t in self.tickets if t.is_zero), None)
        if judged is None:
            return VerdictTable(self.base, self.zero, candidates)
        zero = replace(judged.heldout, p_vs_zero=None)  # against itself
        return VerdictTable(self.base, zero, candidates, judged.id, self.zero.p_vs_base)

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
    arm to run (a ticket, or the base where none beats it) with its cell."""

    tickets: tuple[str, ...]
    fallbacks: tuple[str, ...]
    table: dict[str, tuple[Arm, TransferCell]]

    def to_dict(self) -> dict:
        return {"tickets": list(self.tickets), "fallbacks": list(self.fallbacks),
                "table": {task: {"use": use.key} | cell.to_dict()
                          for task, (use, cell) in self.table.items()}}


@dataclass(frozen=True)
class TransferStudy:
    """Every ticket (with the tasks it was found on) on every task's held-out seeds: base and zero
    rows per task, a cell per (ticket, task), and the greedy cover."""

    policy: str
    heldout_seeds: tuple[int, int]
    tickets: dict[str, list[str]]
    baselines: dict[str, dict[Arm, VerdictRow]]  # task -> the base's and the zero ticket's rows
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


PAIRED_TEST = ("exact McNemar (sign) test on the paired seeds: only the discordant seeds (one arm succeeded, "
               "the other failed) count; p A > B and p B > A are its one-sided p-values, the two-sided p is "
               f"the smaller one doubled (at most 1), and a difference is called where it is below {ALPHA}")


@dataclass(frozen=True)
class ComparedArm:
    """One arm of a comparison: its policy's name, its ticket's id (None: fresh Gaussian noise), its
    arm (the run store's label of its episodes: `Arm.key`) and its episodes on the seeds, in seed order."""

    policy: str
    ticket: str | None
    arm: Arm
    judged: Judged = field(repr=False)

    @property
    def rate(self) -> Rate:
        """Its success rate with the 95% Wilson interval."""
        return self.judged.rate

    @property
    def successes(self) -> tuple[bool, ...]:
        """Each seed's success, in seed order."""
        return tuple(self.judged.successes)

    @property
    def nonfinite(self) -> int:
        """Episodes ended as failures by a NaN or infinite action."""
        return self.judged.nonfinite

    @property
    def label(self) -> str:
        """The policy, and its ticket where it runs one."""
        return self.policy + ("" if self.ticket is None else f" + ticket {self.ticket}")

    def to_dict(self) -> dict:
        return ({"policy": self.policy, "ticket": self.ticket, "arm": self.arm.key} | self.rate.to_dict()
                | {"nonfinite_episodes": self.nonfinite})


@dataclass(frozen=True)
class Comparison:
    """Arms A and B on the same held-out seeds of `task` (`seeds`: the first and the last), paired seed
    by seed: each arm's success, the discordant seeds and the exact paired tests between them
    (`PAIRED_TEST`), computed from the seeds' successes."""

    task: str
    seeds: tuple[int, int]
    a: ComparedArm
    b: ComparedArm

    @property
    def a_only(self) -> int:
        """Seeds where A succeeded and B failed."""
        return sum(a and not b for a, b in zip(self.a.successes, self.b.successes, strict=True))

    @property
    def b_only(self) -> int:
        """Seeds where B succeeded and A failed."""
        return sum(b and not a for a, b in zip(self.a.successes, self.b.successes, strict=True))

    @cached_property
    def p_a_better(self) -> float:
        """One-sided exact paired p-value of A succeeding more often than B."""
        return paired_exact_test(self.a.successes, self.b.successes)

    @cached_property
    def p_b_better(self) -> float:
        """One-sided exact paired p-value of B succeeding more often than A."""
        return paired_exact_test(self.b.successes, self.a.successes)

    @property
    def p_two_sided(self) -> float:
        """The two-sided exact paired p-value: the smaller one-sided one doubled, at most 1."""
        return min(1.0, 2 * min(self.p_a_better, self.p_b_better))

    @property
    def better(self) -> str | None:
        """"A" or "B", the arm the two-sided test finds better (p < ALPHA), else None."""
        if self.p_two_sided >= ALPHA:
            return None
        return "A" if self.p_a_better < self.p_b_better else "B"

    def to_dict(self) -> dict:
        """What `compare --json` prints."""
        return {"task": self.task, "seeds": list(self.seeds), "a": self.a.to_dict(), "b": self.b.to_dict(),
                "discordant": {"a_only": self.a_only, "b_only": self.b_only},
                "p_a_better": self.p_a_better, "p_b_better": self.p_b_better,
                "p_two_sided": self.p_two_sided, "better": self.better, "alpha": ALPHA, "test": PAIRED_TEST}

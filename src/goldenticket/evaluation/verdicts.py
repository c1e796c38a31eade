"""The held-out verdict: is a ticket golden? Arms judged on the same seeds, their paired tests, the
candidates' p-values Holm-adjusted once, here, and the frozen result types."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from typing import TYPE_CHECKING

from goldenticket.evaluation.arms import BASE, ZERO, Arm
from goldenticket.noise import Constant, Gaussian, NoiseSource
from goldenticket.rollout import NONFINITE, EpisodeResult
from goldenticket.stats import Rate, holm_adjust, paired_exact_test

if TYPE_CHECKING:
    from goldenticket.evaluation.runner import Evaluator

ALPHA = 0.05


@dataclass(frozen=True)
class Judged:
    """One arm's episodes on the held-out seeds, in seed order."""

    results: tuple[EpisodeResult, ...] = field(repr=False)

    @property
    def successes(self) -> list[bool]:
        return [r.success for r in self.results]

    @cached_property
    def rate(self) -> Rate:
        return Rate.of(self.successes)

    @property
    def nonfinite(self) -> int:
        """Episodes ended as failures by a NaN or infinite action."""
        return sum(r.cause == NONFINITE for r in self.results)


@dataclass(frozen=True)
class VerdictRow:
    """An arm's held-out verdict: success rate, episodes a NaN or infinite action ended, p-values vs
    base and vs the zero ticket (None: not tested), its diversity where measured, and each
    episode's success (not written to JSON)."""

    rate: Rate
    nonfinite: int = 0
    p_vs_base: float | None = None
    p_vs_zero: float | None = None
    diversity: float | None = None
    successes: tuple[bool, ...] = field(default=(), repr=False, compare=False)  # per seed, in seed order

    @property
    def golden(self) -> bool:
        return self.p_vs_base is not None and self.p_vs_base < ALPHA

    @property
    def verdict(self) -> str:
        return "golden" if self.golden else "not golden"

    def to_dict(self) -> dict:
        """The row as summary.json, ticket metadata and `evaluate --json` write it."""
        out = self.rate.to_dict() | {"nonfinite_episodes": self.nonfinite}
        if self.p_vs_base is not None:
            out |= {"p_vs_base": self.p_vs_base, "golden": self.golden, "verdict": self.verdict}
        if self.p_vs_zero is not None:
            out["p_vs_zero"] = self.p_vs_zero
        if self.diversity is not None:
            out["diversity"] = self.diversity
        return out


@dataclass(frozen=True)
class Verdict:
    """Arms judged on the same seeds, the base among them: each arm's episodes (`arms`) and its row
    (`rows`). Every arm but the base is tested against the base, and, where the zero ticket is
    judged, every candidate against the zero ticket (one-sided exact paired tests); the candidates
    (`Arm.candidate`: tickets, a mixture) are tested on the same seeds, so their p-values are
    Holm-adjusted over them. The rows are computed from the episodes, once, and neither changes:
    nothing adjusts them again."""

    arms: Mapping[Arm, Judged]

    def __post_init__(self):
        object.__setattr__(self, "arms", MappingProxyType(dict(self.arms)))

    @cached_property
    def rows(self) -> Mapping[Arm, VerdictRow]:
        """Each arm's row, in the order of `arms`."""
        vs_base = self._adjusted({arm: self._test(arm, BASE) for arm in self.arms if arm != BASE})
        vs_zero = {} if ZERO not in self.arms else self._adjusted(
            {arm: self._test(arm, ZERO) for arm in self.candidates})
        return MappingProxyType({arm: VerdictRow(judged.rate, judged.nonfinite, vs_base.get(arm),
                                                 vs_zero.get(arm), successes=tuple(judged.successes))
                                 for arm, judged in self.arms.items()})

    @property
    def candidates(self) -> list[Arm]:
        """The arms Holm adjusts over, in order."""
        return [arm for arm in self.arms if arm.candidate]

    def _test(self, arm: Arm, against: Arm) -> float:
        """The one-sided exact paired test of `arm` better than `against`, not adjusted."""
        return paired_exact_test(self.arms[arm].successes, self.arms[against].successes)

    def _adjusted(self, p_values: dict[Arm, float]) -> dict[Arm, float]:
        """`p_values`, the candidates' Holm-adjusted over them."""
        adjusted = holm_adjust([p_values[arm] for arm in self.candidates])
        return p_values | dict(zip(self.candidates, adjusted, strict=True))


def to_dicts(rows: Mapping[Arm, VerdictRow]) -> dict[str, dict]:
    """Verdict rows by arm, as JSON writes them (keyed by `Arm.key`)."""
    return {arm.key: row.to_dict() for arm, row in rows.items()}


@dataclass(frozen=True)
class MultitaskVerdict:
    """Several tasks' verdict: rows per task and on average by arm, the tickets judged, the tasks
    each significantly regresses on, and the best ticket (None: none qualifies)."""

    tasks: dict[str, Mapping[Arm, VerdictRow]]
    average: Mapping[Arm, VerdictRow]
    tickets: tuple[Arm, ...]
    regressions: dict[Arm, list[str]]
    no_regression: bool
    best: Arm | None

    def to_dict(self) -> dict:
        return {"tasks": {name: to_dicts(rows) for name, rows in self.tasks.items()},
                "average": to_dicts(self.average), "tickets": [t.key for t in self.tickets],
                "regressions": {t.key: tasks for t, tasks in self.regressions.items()},
                "no_regression": self.no_regression, "best": self.best and self.best.key}


def judge(evaluator: Evaluator, sources: Mapping[Arm, NoiseSource], seeds: Sequence[int],
          base: NoiseSource | None = None, task: str | None = None) -> Verdict:
    """The base policy and each source on the same held-out seeds (of `task`, default the
    engine's first), recorded under their arms' keys: a `Verdict`. Sources of the same constant
    noise share one run's episodes."""
    first = same_constants(sources)
    run = {BASE: base or Gaussian()} | {arm: source for arm, source in sources.items() if first[arm] == arm}
    results = evaluator.run([(arm.key, source, seeds) for arm, source in run.items()], task)
    ran = dict(zip(run, results, strict=True))
    return judged_arms({BASE: ran[BASE]} | {arm: ran[first[arm]] for arm in sources})


def judge_size(sources: Mapping[Arm, NoiseSource], seeds: int) -> int:
    """The episodes `judge` runs for `sources` on `seeds` seeds, the base's included."""
    return seeds * (len(set(same_constants(sources).values())) + 1)


def same_constants(sources: Mapping[Arm, NoiseSource]) -> dict[Arm, Arm]:
    """Each arm -> the first arm whose source is the same constant noise (itself if none is)."""
    first: dict[tuple, Arm] = {}
    return {arm: first.setdefault((s.noise.shape, s.noise.dtype.str, s.noise.tobytes()), arm)
            if isinstance(s, Constant) else arm for arm, s in sources.items()}


def judged_arms(outcomes: Mapping[Arm, Sequence[EpisodeResult]]) -> Verdict:
    """Each arm's paired episodes (the base's among them) judged: a `Verdict`."""
    return Verdict({arm: Judged(tuple(results)) for arm, results in outcomes.items()})


def pooled(per_task: Mapping[str, Verdict]) -> Verdict:
    """Arms judged on every task's episodes together (equal seeds per task: the task average)."""
    arms = next(iter(per_task.values())).arms
    return judged_arms({arm: [r for verdict in per_task.values() for r in verdict.arms[arm].results]
                        for arm in arms})


def regressions(per_task: Mapping[str, Verdict], arm: Arm) -> list[str]:
    """Tasks on which `arm` is significantly worse than the base (one-sided exact paired test,
    p < ALPHA, not adjusted: a stricter guard)."""
    return [task for task, verdict in per_task.items()
            if paired_exact_test(verdict.arms[BASE].successes, verdict.arms[arm].successes) < ALPHA]


def multitask_verdict(per_task: Mapping[str, Verdict], no_regression: bool) -> MultitaskVerdict:
    """Per task and on average: base, zero and each ticket with its p-values (Holm-adjusted over the
    tickets), the tasks each ticket significantly regresses on, and the best ticket: the highest
    average success, among tickets that regress nowhere if `no_regression` (None if none is left)."""
    average = pooled(per_task)
    tickets = average.candidates
    regressing = {t: regressions(per_task, t) for t in tickets}
    allowed = [t for t in tickets if not (no_regression and regressing[t])]
    rows = average.rows
    ranked = sorted(allowed, key=lambda t: (-rows[t].rate.success_rate, rows[t].p_vs_base))
    return MultitaskVerdict({name: verdict.rows for name, verdict in per_task.items()}, rows, tuple(tickets),
                            regressing, no_regression, ranked[0] if ranked else None)


def p_value_note(n_tickets: int) -> str:
    """How to read the p-values of a verdict over `n_tickets` tickets (Holm only when it adjusts
    something: over one ticket it changes nothing)."""
    adjusted = {0: "not adjusted", 1: "not adjusted (one ticket tested)"}.get(
        n_tickets, f"Holm-adjusted over the {n_tickets} tickets tested")
    return ("p-values: one-sided exact McNemar (sign) test on the paired held-out seeds, ticket "
            f"better than base (p vs base) or than the zero ticket (p vs zero), {adjusted}. "
            f"'golden' means p vs base < {ALPHA}.")

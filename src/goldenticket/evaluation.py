"""Recorded, resumable evaluation, and the held-out verdict: is a ticket golden?"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property

from goldenticket.noise import Gaussian, NoiseSource
from goldenticket.rollout import Engine, Episode, EpisodeResult
from goldenticket.stats import Rate, holm_adjust, paired_exact_test
from goldenticket.store import EpisodeRow, RunStore
from goldenticket.tasks.base import seed_set_of

ALPHA = 0.05
Job = tuple[str, NoiseSource, Sequence[int]]  # (label, noise source, seeds)


class Evaluator:
    """Runs (label, noise source, seeds) through the engine, recording every episode.

    Episodes already in the store are read back, not re-run, so a killed run resumes where it
    stopped. The label identifies the noise source: "base", "zero", or a ticket id.
    """

    def __init__(self, engine: Engine, store: RunStore | None = None,
                 on_done: Callable[[int], None] | None = None):
        self.engine, self.store, self.on_done = engine, store, on_done

    def run(self, jobs: Sequence[Job], task: str | None = None) -> list[list[EpisodeResult]]:
        """Results per job, in seed order, on `task` (default: the engine's first); new episodes of
        all jobs run in one engine call."""
        task = task or self.engine.task.name
        known = {}
        if self.store is not None:
            for label in {label for label, _, _ in jobs}:
                for row in self.store.episodes(ticket_id=label, task=task):
                    known[label, row.seed] = EpisodeResult(row.seed, row.success, row.ret,
                                                           row.length, row.wall_time)
        todo = [(label, Episode(source, seed)) for label, source, seeds in jobs for seed in seeds
                if (label, seed) not in known]

        def keep(start: int, results: list[EpisodeResult]) -> None:
            labels = [label for label, _ in todo[start : start + len(results)]]
            known.update({(label, r.seed): r for label, r in zip(labels, results, strict=True)})
            if self.store is not None:  # recorded as it finishes: a killed run loses little
                self.store.record(EpisodeRow(label, task, r.seed, seed_set_of(r.seed), r.success,
                                             r.ret, r.length, r.wall_time)
                                  for label, r in zip(labels, results, strict=True))
            if self.on_done:
                self.on_done(len(results))

        if self.on_done:  # episodes read back from the store count as done
            self.on_done(sum(len(seeds) for _, _, seeds in jobs) - len(todo))
        self.engine.evaluate([ep for _, ep in todo], keep, task)
        return [[known[label, s] for s in seeds] for label, _, seeds in jobs]


@dataclass
class Judged:
    """One noise source's held-out outcome, with its tests against the base and zero ticket."""

    label: str
    results: list[EpisodeResult] = field(repr=False)  # per held-out seed, in seed order
    p_value: float | None = None  # one-sided exact paired test vs base; None for the base
    p_vs_zero: float | None = None  # the same test vs the zero ticket; None for base and zero

    @property
    def successes(self) -> list[bool]:
        return [r.success for r in self.results]

    @cached_property
    def rate(self) -> Rate:
        return Rate.of(self.successes)

    @property
    def golden(self) -> bool:
        return self.p_value is not None and self.p_value < ALPHA

    def to_dict(self) -> dict:
        out = self.rate.to_dict()
        if self.p_value is not None:
            out |= {"p_value": self.p_value, "golden": self.golden,
                    "verdict": "golden" if self.golden else "not golden"}
        if self.p_vs_zero is not None:
            out["p_vs_zero"] = self.p_vs_zero
        return out


def judge(evaluator: Evaluator, sources: dict[str, NoiseSource], seeds: Sequence[int],
          base: NoiseSource | None = None, task: str | None = None) -> dict[str, Judged]:
    """The base policy and each source on the same held-out seeds (of `task`, default the
    engine's first), each tested against base and, when a source is labelled "zero", every other
    source also against the zero ticket."""
    jobs = [("base", base or Gaussian(), seeds)] + [(k, s, seeds) for k, s in sources.items()]
    return judged_arms({label: results for (label, _, _), results in zip(jobs, evaluator.run(jobs, task),
                                                                      strict=True)})


def judged_arms(outcomes: dict[str, list[EpisodeResult]]) -> dict[str, Judged]:
    """Each arm's paired episodes (keyed "base", "zero", then tickets) judged: p-values vs base,
    and vs zero where a "zero" arm exists."""
    judged = {label: Judged(label, results) for label, results in outcomes.items()}
    for label in set(judged) - {"base"}:
        judged[label].p_value = paired_exact_test(judged[label].successes, judged["base"].successes)
    if "zero" in judged:
        for label in set(judged) - {"base", "zero"}:
            judged[label].p_vs_zero = paired_exact_test(judged[label].successes,
                                                        judged["zero"].successes)
    return judged


def pooled(per_task: dict[str, dict[str, Judged]]) -> dict[str, Judged]:
    """Arms judged on every task's episodes together (equal seeds per task: the task average)."""
    labels = next(iter(per_task.values()))
    return judged_arms({label: [r for judged in per_task.values() for r in judged[label].results]
                   for label in labels})


def regressions(per_task: dict[str, dict[str, Judged]], label: str) -> list[str]:
    """Tasks on which arm `label` is significantly worse than the base (one-sided exact paired
    test, p < ALPHA, not adjusted: a stricter guard)."""
    return [task for task, judged in per_task.items()
            if paired_exact_test(judged["base"].successes, judged[label].successes) < ALPHA]


def adjust_for_multiplicity(judged: dict[str, Judged], ticket_ids: list[str]) -> None:
    """Testing k tickets on the same seeds: Holm-adjust their p-values so 'golden' stays honest."""
    for attr in ("p_value", "p_vs_zero"):
        adjusted = holm_adjust([getattr(judged[t], attr) for t in ticket_ids])
        for ticket_id, p in zip(ticket_ids, adjusted, strict=True):
            setattr(judged[ticket_id], attr, p)


def p_value_note(n_tickets: int) -> str:
    """How to read the p-values of a verdict over `n_tickets` tickets."""
    return ("p-values: one-sided exact McNemar (sign) test on the paired held-out seeds, ticket "
            "better than base (p vs base) or than the zero ticket (p vs zero), Holm-adjusted over "
            f"the {n_tickets} tickets tested. 'golden' means p vs base < {ALPHA}.")

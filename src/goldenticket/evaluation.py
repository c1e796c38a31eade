"""Recorded, resumable evaluation, and the held-out verdict: is a ticket golden?"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property

from tqdm import tqdm

from goldenticket.config import MAX_NONFINITE, EngineOptions, check_max_nonfinite
from goldenticket.errors import OptionError, UserError
from goldenticket.noise import Constant, Gaussian, NoiseSource
from goldenticket.rollout import NONFINITE, Engine, Episode, EpisodeResult
from goldenticket.seeds import SEED_SETS, seed_set_of
from goldenticket.stats import Rate, holm_adjust, paired_exact_test
from goldenticket.store import EpisodeRow, RunStore

ZERO_MARK = " (w = 0)"  # ends the zero ticket's label in the verdict table when it is judged as a ticket

ALPHA = 0.05
BROKEN_UNDER = ("base", "zero")  # both non-finite too often: the policy or its adapter is broken
Job = tuple[str, NoiseSource, Sequence[int]]  # (label, noise source, seeds)


class Bar(tqdm):
    """A tqdm bar that Ctrl-C or SIGTERM may cut off inside its constructor: then, half built, it has
    nothing to close (tqdm's own __del__ would print a traceback after the one-line stop message)."""

    def __del__(self):
        if hasattr(self, "pos"):
            super().__del__()


class Evaluator:
    """Runs (label, noise source, seeds) through the engine, recording every episode.

    Episodes already in the store are read back, not re-run, so a killed run resumes where it
    stopped. The label identifies the noise source: "base", "zero", or a ticket id. Two checks
    stop a run with a UserError: a new episode whose initial observation differs from the one
    first recorded for its task and seed (in the store, or in memory without one; the episode is
    not recorded), and a policy that ended more than `max_nonfinite` of the held-out episodes of
    both the base and the zero ticket (of the base where no zero ticket runs) with a NaN or infinite
    action: it or its adapter is broken. Any other non-finite episode is a failure of its arm.
    """

    def __init__(self, engine: Engine, store: RunStore | None = None,
                 on_done: Callable[[int], None] | None = None, max_nonfinite: float = MAX_NONFINITE):
        check_max_nonfinite(max_nonfinite)
        self.engine, self.store, self.on_done, self.max_nonfinite = engine, store, on_done, max_nonfinite
        self._digests: dict[tuple[str, int], str] = {}  # (task, seed): first initial digest, without a store

    @classmethod
    @contextmanager
    def open(cls, policy, tasks, options: EngineOptions | None = None, store: RunStore | None = None,
             objective: str = "success", loaded=None) -> Iterator[Evaluator]:
        """An evaluator on its own engine for `policy` on `tasks` (one task or several), where
        `options` say (workers, backend, address, max_nonfinite, device); `loaded`: the policy already
        built, used in-process. The engine's workers stop when the block ends."""
        options = options or EngineOptions()
        with Engine(policy, tasks, objective=objective, workers=options.workers, backend=options.backend,
                    address=options.address, loaded=loaded, device=options.device) as engine:
            yield cls(engine, store, max_nonfinite=options.max_nonfinite)

    def progress(self, total: int | None, desc: str) -> tqdm:
        """A tqdm bar that this evaluator advances as episodes finish (or are read back)."""
        bar = Bar(total=total, desc=desc, unit="ep", dynamic_ncols=True)
        self.on_done = bar.update
        return bar

    def run(self, jobs: Sequence[Job], task: str | None = None) -> list[list[EpisodeResult]]:
        """Results per job, in seed order, on `task` (default: the engine's first); new episodes of
        all jobs run in one engine call, ordered by seed (each episode's result depends only on its
        noise source and seed, and a seed's later resets restore its first: tasks/metaworld.py)."""
        task = task or self.engine.task.name
        known = {}
        if self.store is not None:
            for label in {label for label, _, _ in jobs}:
                for row in self.store.episodes(ticket_id=label, task=task):
                    known[label, row.seed] = EpisodeResult(row.seed, row.success, row.ret, row.length,
                                                           row.wall_time, cause=row.cause)
        todo = [(label, Episode(source, seed)) for label, source, seeds in jobs for seed in seeds
                if (label, seed) not in known]
        todo.sort(key=lambda item: item[1].seed)  # a seed's arms side by side: its reset is kept, not redone
        heldout: dict[str, list[int]] = {}
        for label, _, seeds in jobs:
            heldout.setdefault(label, []).extend(s for s in seeds if s in SEED_SETS["heldout"])
        self._check_nonfinite(heldout, known)

        def keep(start: int, results: list[EpisodeResult]) -> None:
            labels = [label for label, _ in todo[start : start + len(results)]]
            same = self._same_initial_states(task, results)
            kept = [(label, r) for label, r, ok in zip(labels, results, same, strict=True) if ok]
            known.update({(label, r.seed): r for label, r in kept})
            if self.store is not None:  # recorded as it finishes: a killed run loses little
                self.store.record(EpisodeRow(label, task, r.seed, seed_set_of(r.seed), r.success,
                                             r.ret, r.length, r.wall_time, r.cause) for label, r in kept)
            if not all(same):
                seed = next(r.seed for r, ok in zip(results, same, strict=True) if not ok)
                where = "in worker processes" if self.engine.in_workers else "from one episode to the next"
                raise UserError(f"task {task!r}: reset(seed={seed}) does not fix the initial state {where}: "
                                "it gave another initial observation than this run's first episode on "
                                "that seed; seed every random draw of reset from its seed")
            if self.on_done:
                self.on_done(len(results))
            self._check_nonfinite(heldout, known)

        if self.on_done:  # episodes read back from the store count as done
            self.on_done(sum(len(seeds) for _, _, seeds in jobs) - len(todo))
        self.engine.evaluate([ep for _, ep in todo], keep, task)
        return [[known[label, s] for s in seeds] for label, _, seeds in jobs]

    def _same_initial_states(self, task: str, results: list[EpisodeResult]) -> list[bool]:
        """Whether each episode began in the state first recorded for its seed (the first recorded
        is each seed's first episode)."""
        pairs = [(r.seed, r.digest) for r in results]
        if self.store is not None:
            first = self.store.first_digests(task, pairs)
        else:
            first = [self._digests.setdefault((task, seed), digest) for seed, digest in pairs]
        return [r.digest == f for r, f in zip(results, first, strict=True)]

    def _check_nonfinite(self, heldout: dict[str, list[int]], known: dict) -> None:
        """OptionError if more than max_nonfinite of the held-out episodes (`heldout`: seeds by label)
        of both the base and the zero ticket, on the seeds they share, ended with a non-finite action
        among those finished (`known`); of the base alone in a run without a zero ticket. A ticket's
        non-finite episodes are its failures, never a stop."""
        arms = [label for label in BROKEN_UNDER if label in heldout]
        if "base" not in arms:
            return
        shared = set(heldout["base"]).intersection(*(heldout[label] for label in arms))
        seeds = [s for s in heldout["base"] if s in shared]
        ended = {label: [known[label, s] for s in seeds if (label, s) in known
                         and known[label, s].cause == NONFINITE] for label in arms}
        if all(len(results) > self.max_nonfinite * len(seeds) for results in ended.values()):
            raise OptionError(self._nonfinite_line(ended, len(seeds)), "max_nonfinite")

    def _nonfinite_line(self, ended: dict[str, list[EpisodeResult]], n: int) -> str:
        """The stop's line: the non-finite episodes of base (and zero) among their `n` held-out ones,
        and the first of them."""
        arm, first = min(((label, r) for label, results in ended.items() for r in results),
                         key=lambda item: item[1].seed)  # ties: the base's, listed first
        line = (f"policy {self.engine.label!r} returned NaN or infinite actions in {len(ended['base'])} of "
                f"the {n} held-out episodes of base")
        if "zero" not in ended:
            return (line + f", more than max_nonfinite {self.max_nonfinite:g} of them (the first on seed "
                    f"{first.seed}, at step {first.length})")
        return (line + f" and {len(ended['zero'])} of zero, more than max_nonfinite {self.max_nonfinite:g} "
                f"of them in each (the first on seed {first.seed}, at step {first.length}, under {arm}): it "
                "breaks under its own noise and under the zero ticket: the policy or its adapter is broken")


@dataclass
class Judged:
    """One noise source's held-out outcome, with its tests against the base and zero ticket."""

    label: str
    results: list[EpisodeResult] = field(repr=False)  # per held-out seed, in seed order
    p_vs_base: float | None = None  # one-sided exact paired test vs base; None for the base
    p_vs_zero: float | None = None  # the same test vs the zero ticket; None for base and zero

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

    def row(self) -> VerdictRow:
        return VerdictRow(self.rate, self.nonfinite, self.p_vs_base, self.p_vs_zero,
                          successes=tuple(self.successes))

    def to_dict(self) -> dict:
        return self.row().to_dict()


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


def to_dicts(rows: dict[str, VerdictRow]) -> dict[str, dict]:
    """Verdict rows by arm, as JSON writes them."""
    return {label: row.to_dict() for label, row in rows.items()}


@dataclass(frozen=True)
class MultitaskVerdict:
    """Several tasks' verdict: rows per task and on average by arm, the tickets judged, the tasks
    each significantly regresses on, and the best ticket (None: none qualifies)."""

    tasks: dict[str, dict[str, VerdictRow]]
    average: dict[str, VerdictRow]
    tickets: tuple[str, ...]
    regressions: dict[str, list[str]]
    no_regression: bool
    best: str | None

    def to_dict(self) -> dict:
        return {"tasks": {name: to_dicts(rows) for name, rows in self.tasks.items()},
                "average": to_dicts(self.average), "tickets": list(self.tickets),
                "regressions": self.regressions, "no_regression": self.no_regression, "best": self.best}


def judge(evaluator: Evaluator, sources: dict[str, NoiseSource], seeds: Sequence[int],
          base: NoiseSource | None = None, task: str | None = None) -> dict[str, Judged]:
    """The base policy and each source on the same held-out seeds (of `task`, default the
    engine's first), each tested against base and, when a source is labelled "zero", every other
    source also against the zero ticket. Sources of the same constant noise share one run's episodes."""
    first = same_constants(sources)
    jobs = [("base", base or Gaussian(), seeds)]
    jobs += [(label, source, seeds) for label, source in sources.items() if first[label] == label]
    results = dict(zip((label for label, _, _ in jobs), evaluator.run(jobs, task), strict=True))
    return judged_arms({"base": results["base"]} | {label: results[first[label]] for label in sources})


def judge_size(sources: dict[str, NoiseSource], seeds: int) -> int:
    """The episodes `judge` runs for `sources` on `seeds` seeds, the base's included."""
    return seeds * (len(set(same_constants(sources).values())) + 1)


def same_constants(sources: dict[str, NoiseSource]) -> dict[str, str]:
    """Each label -> the first label whose source is the same constant noise (itself if none is)."""
    first: dict[tuple, str] = {}
    return {label: first.setdefault((s.noise.shape, s.noise.dtype.str, s.noise.tobytes()), label)
            if isinstance(s, Constant) else label for label, s in sources.items()}


def judged_arms(outcomes: dict[str, list[EpisodeResult]]) -> dict[str, Judged]:
    """Each arm's paired episodes (keyed "base", "zero", then tickets) judged: p-values vs base,
    and vs zero where a "zero" arm exists."""
    judged = {label: Judged(label, results) for label, results in outcomes.items()}
    for label in set(judged) - {"base"}:
        judged[label].p_vs_base = paired_exact_test(judged[label].successes, judged["base"].successes)
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


def multitask_verdict(per_task: dict[str, dict[str, Judged]], ticket_ids: list[str],
                      no_regression: bool) -> MultitaskVerdict:
    """Per task and on average: base, zero and each ticket with p-values (Holm-adjusted over the
    tickets), the tasks each ticket significantly regresses on, and the best ticket: the highest
    average success, among tickets that regress nowhere if `no_regression` (None if none is left)."""
    average = pooled(per_task)
    for judged in [*per_task.values(), average]:
        adjust_for_multiplicity(judged, ticket_ids)
    regressing = {t: regressions(per_task, t) for t in ticket_ids}
    allowed = [t for t in ticket_ids if not (no_regression and regressing[t])]
    ranked = sorted(allowed, key=lambda t: (-average[t].rate.success_rate, average[t].p_vs_base))
    return MultitaskVerdict({name: _rows(judged) for name, judged in per_task.items()}, _rows(average),
                            tuple(ticket_ids), regressing, no_regression, ranked[0] if ranked else None)


def _rows(judged: dict[str, Judged]) -> dict[str, VerdictRow]:
    return {label: j.row() for label, j in judged.items()}


def adjust_for_multiplicity(judged: dict[str, Judged], ticket_ids: list[str]) -> None:
    """Testing k tickets on the same seeds: Holm-adjust their p-values so 'golden' stays honest."""
    for attr in ("p_vs_base", "p_vs_zero"):
        adjusted = holm_adjust([getattr(judged[t], attr) for t in ticket_ids])
        for ticket_id, p in zip(ticket_ids, adjusted, strict=True):
            setattr(judged[ticket_id], attr, p)


def p_value_note(n_tickets: int) -> str:
    """How to read the p-values of a verdict over `n_tickets` tickets (Holm only when it adjusts
    something: over one ticket it changes nothing)."""
    adjusted = {0: "not adjusted", 1: "not adjusted (one ticket tested)"}.get(
        n_tickets, f"Holm-adjusted over the {n_tickets} tickets tested")
    return ("p-values: one-sided exact McNemar (sign) test on the paired held-out seeds, ticket "
            f"better than base (p vs base) or than the zero ticket (p vs zero), {adjusted}. "
            f"'golden' means p vs base < {ALPHA}.")

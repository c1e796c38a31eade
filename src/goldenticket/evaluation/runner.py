"""Recorded, resumable evaluation: (label, noise source, seeds) through the engine, every episode
kept in the run store and read back on a rerun, with its checks (initial states, non-finite
actions) and its progress bars."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from tqdm import tqdm

from goldenticket.config import MAX_NONFINITE, EngineOptions, check_max_nonfinite
from goldenticket.errors import OptionError, UserError
from goldenticket.evaluation.arms import BASE, ZERO
from goldenticket.noise import NoiseSource
from goldenticket.rollout import NONFINITE, Engine, Episode, EpisodeResult
from goldenticket.seeds import SEED_SETS, seed_set_of
from goldenticket.store import EpisodeRow, RunStore

BROKEN_UNDER = (BASE.key, ZERO.key)  # both non-finite too often: the policy or its adapter is broken
Job = tuple[str, NoiseSource, Sequence[int]]  # (label: the run store's, an arm's key; noise source, seeds)


class Bar(tqdm):
    """A tqdm bar that Ctrl-C or SIGTERM may cut off inside its constructor: then, half built, it has
    nothing to close (tqdm's own __del__ would print a traceback after the one-line stop message)."""

    def __del__(self):
        if hasattr(self, "pos"):
            super().__del__()


class Evaluator:
    """Runs (label, noise source, seeds) through the engine, recording every episode.

    Episodes already in the store are read back, not re-run, so a killed run resumes where it
    stopped. The label identifies the noise source: an arm's key ("base", "zero", a ticket id). Two checks
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
        `options` say (workers, backend, address, max_nonfinite, device, step_timeout, a LeRobot
        checkpoint's settings); `loaded`: the policy already built, used in-process. The engine's
        workers stop when the block ends."""
        options = options or EngineOptions()
        with Engine(policy, tasks, objective=objective, workers=options.workers, backend=options.backend,
                    address=options.address, loaded=loaded, device=options.device,
                    settings=options.policy_settings(),
                    step_timeout=options.step_timeout) as engine:
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
        if BASE.key not in arms:
            return
        shared = set(heldout[BASE.key]).intersection(*(heldout[label] for label in arms))
        seeds = [s for s in heldout[BASE.key] if s in shared]
        ended = {label: [known[label, s] for s in seeds if (label, s) in known
                         and known[label, s].cause == NONFINITE] for label in arms}
        if all(len(results) > self.max_nonfinite * len(seeds) for results in ended.values()):
            raise OptionError(self._nonfinite_line(ended, len(seeds)), "max_nonfinite")

    def _nonfinite_line(self, ended: dict[str, list[EpisodeResult]], n: int) -> str:
        """The stop's line: the non-finite episodes of base (and zero) among their `n` held-out ones,
        and the first of them."""
        arm, first = min(((label, r) for label, results in ended.items() for r in results),
                         key=lambda item: item[1].seed)  # ties: the base's, listed first
        line = (f"policy {self.engine.label!r} returned NaN or infinite actions in {len(ended[BASE.key])} of "
                f"the {n} held-out episodes of base")
        if ZERO.key not in ended:
            return (line + f", more than max_nonfinite {self.max_nonfinite:g} of them (the first on seed "
                    f"{first.seed}, at step {first.length})")
        return (line + f" and {len(ended[ZERO.key])} of zero, more than max_nonfinite {self.max_nonfinite:g} "
                f"of them in each (the first on seed {first.seed}, at step {first.length}, under {arm}): it "
                "breaks under its own noise and under the zero ticket: the policy or its adapter is broken")

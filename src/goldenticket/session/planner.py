"""What is due in a session, from its plan and the scores in its store: the next search round or
the confirm phase, planned (by `race`'s pure functions) the first time anyone asks after the last
score before it; the due episode, none once a sequential session's test has decided; and the
verdict once the session is complete."""

from __future__ import annotations

from goldenticket.session.race import Race, next_episodes, race
from goldenticket.session.store import Store
from goldenticket.session.verdict import (
    Pairs,
    SessionVerdict,
    confirm_pairs,
    fixed_verdict,
    sequential_test,
    sequential_verdict,
)
from goldenticket.stats import Sequential


class Planner:
    """The plan of one store, replayed from its scores."""

    def __init__(self, store: Store):
        self._store = store
        self.plan = store.plan

    def due(self) -> int | None:
        """The first unscored episode, unless the sequential test has decided."""
        due = self._store.first_unscored()
        if due is None or self._store.confirm_start() is None:
            return due
        test = self._test()
        return None if test and test.decision else due

    def plan_next_if_due(self) -> None:
        """Plan the next search round or the confirm phase once every planned episode is scored."""
        if not self._round_due():
            return
        with self._store.transaction():
            if not self._round_due():  # another process planned it meanwhile
                return
            planned, (phase, arms) = len(self._store.search()), next_episodes(self.plan, self._race())
            self._store.plan_episodes(planned, phase, arms)

    def planned_after(self, episode: int) -> int | None:
        """The first episode of the rounds planned from `episode`'s score, if any."""
        return next((end for end in self._race().ends if end > episode), None)

    def search_round(self, episode: int) -> tuple[int, int]:
        """The search round `episode` belongs to (the first is 1), and how many candidates run in it."""
        search, ends = self._store.search(), self._race().ends
        done = sum(end <= episode for end in ends)
        return done + 1, len({arm for arm, _ in search[ends[done - 1] if done else 0:ends[done]]})

    def verdict(self) -> SessionVerdict:
        """The complete session's verdict (`verdict.fixed_verdict` or `sequential_verdict`)."""
        if self.plan.stopping == "fixed":
            return fixed_verdict(self.plan, self._store.confirmed())
        scored, _, stopped_at = self._store.tally()
        return sequential_verdict(self.plan, self._pairs(), scored, stopped_at)

    def _round_due(self) -> bool:
        """Whether every planned episode is scored and the confirm phase not planned yet."""
        scored, planned, _ = self._store.tally()
        return scored == planned and self._store.confirm_start() is None

    def _race(self) -> Race:
        return race(self.plan, self._store.candidates, self._store.search())

    def _test(self) -> Sequential | None:
        """The sequential sign test on the confirm pairs scored so far; None for a fixed session."""
        return None if self.plan.stopping == "fixed" else sequential_test(self.plan, self._pairs())

    def _pairs(self) -> Pairs:
        return confirm_pairs(self._store.confirmed(), next(iter(self._store.finalists()), None))

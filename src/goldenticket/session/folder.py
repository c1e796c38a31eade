"""A real-robot search session scored by a person: one folder, its store (`session.sqlite`) and
the files derived from it.

Every score is written the moment it is entered; only the due episode (the first unscored one)
can be scored, and what is planned next is a function of the seed and the scores (`planner`), so
a restart resumes where it stopped. The files beside the store (`derived`: the finalists'
tickets, and once complete summary.json and verdict.png) are brought in line with it whenever
the session is opened or asked what is due.
"""

from __future__ import annotations

from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.session.derived import check_free, remove_verdict, save_tickets, save_verdict
from goldenticket.session.episode import NextEpisode
from goldenticket.session.planner import Planner
from goldenticket.session.race import BASE, Plan, candidates
from goldenticket.session.stage import stage
from goldenticket.session.store import FILE, Store
from goldenticket.session.verdict import SessionVerdict
from goldenticket.tickets import Ticket, TicketRecord


class ScoreConflict(UserError):
    """A score for an episode scored already or not yet due, or an undo of an episode that is
    not the last one scored; `details` names the due or the last scored episode."""

    def __init__(self, message: str, **details: int | None):
        super().__init__(message)
        self.details = details


class Session:
    """One session folder. Every method is a short transaction, so several processes (a server,
    a terminal scorer, the robot's Python loop) can share it."""

    def __init__(self, folder: str | Path):
        self._store = Store(folder)
        self._planner = Planner(self._store)
        self.path, self.plan = self._store.path, self._store.plan
        self.name = self.path.parent.resolve().name
        self._refresh()

    @classmethod
    def new(cls, folder: str | Path, plan: Plan) -> Session:
        """Plan the first search round and write it; refuses a folder that holds a session already,
        or another run (`derived.check_free`)."""
        path = Path(folder) / FILE
        if path.exists():
            raise UserError(f"{path} exists: a session is already planned there (serve or score it)")
        check_free(path.parent)
        Store.create(folder, plan, *candidates(plan))
        return cls(folder)

    def next(self) -> NextEpisode | None:
        """The due episode (planning the next round or the confirm phase once the last is scored),
        or None when the session is complete."""
        due = self._refresh()["due"]
        return None if due is None else self.episode(due)

    def episode(self, episode: int) -> NextEpisode:
        """What the robot runs for one planned episode."""
        arm = self._store.arm(episode)
        if arm == BASE:
            return NextEpisode(episode, BASE, None, [self.plan.seed, episode], self.plan.noise_shape)
        return NextEpisode(episode, arm, self._store.noise(arm), None, self.plan.noise_shape)

    def score(self, episode: int, success: bool, note: str = "", scene: str | None = None) -> None:
        """Record the due episode's outcome, committed at once; ScoreConflict (naming the due
        episode) for any other."""
        self._check_planned(episode)
        self._planner.plan_next_if_due()
        with self._store.transaction():
            due = self._planner.due()
            if episode != due:
                why = "scored already" if self._store.is_scored(episode) else "not due"
                then = "the session is complete" if due is None else f"the due episode is {due}"
                raise ScoreConflict(f"episode {episode} is {why}; {then}", due=due)
            self._store.enter_score(episode, success, note, scene)

    def undo(self, episode: int) -> None:
        """Unscore `episode`, which must be the last score entered (and drop the unstarted rounds
        planned from it); ScoreConflict (naming the last scored episode) otherwise."""
        self._check_planned(episode)
        with self._store.transaction():
            last = self._store.last_scored()
            if episode != last:
                raise ScoreConflict(f"episode {episode} is not the last one scored; that is {last}",
                                    last_scored=last)
            later = self._planner.planned_after(episode)
            self._store.unscore(episode)
            if later is not None:
                self._store.drop_from(later)

    def status(self) -> dict:
        """Scored episodes and the most the session may run (`total`), those planned so far, the
        due and the last scored episode, the stopping rule, what is due in words (`stage`, never
        the arm), and once the session is complete its `verdict` (a SessionVerdict)."""
        return self._refresh()

    def verdict(self) -> SessionVerdict:
        """The confirm phase's success per arm with Wilson intervals, and each finalist's one-sided
        p-value against the base. Fixed: Holm-adjusted over the two finalists, from a paired exact
        test when scene ids pair every finalist episode with a base episode, else Fisher's exact
        test (unpaired). Sequential: the sequential sign test on the pairs, and when and why the
        session stopped (`stopping`)."""
        status = self.status()
        if "verdict" in status:
            return status["verdict"]
        raise UserError(f"the session is not finished: {status['scored']} of at most {status['total']} "
                        "episodes scored")

    def scores(self) -> list[dict]:
        """Every planned episode with its score so far and its place in the order of entry (arm
        names included: for the record, not for the operator's screen)."""
        self._refresh()
        return self._store.rows()

    def _refresh(self) -> dict:
        """Plan the next round or the confirm phase if due, bring the derived files in line with
        the store, and return the status."""
        self._store.check()
        self._planner.plan_next_if_due()
        save_tickets(self.path.parent, self._store.candidates, self._store.finalists(), self._ticket)
        status = self._status()
        self._save_verdict(status.get("verdict"))
        return status

    def _status(self) -> dict:
        scored, planned, _ = self._store.tally()
        due, confirm = self._planner.due(), self._store.confirm_start()
        status = {"scored": scored, "total": self.plan.episodes, "planned": planned,
                  "phase": "search" if confirm is None else "confirm", "due": due,
                  "last_scored": self._store.last_scored(), "stopping": self.plan.stopping,
                  "stage": stage(self.plan, due, confirm, self._planner.search_round)}
        if due is None and confirm is not None:
            status["verdict"] = self._planner.verdict()
        return status

    def _ticket(self, arm: str) -> Ticket:
        """A finalist as a ticket for the policy, with its search record."""
        won, episodes = self._store.search_record()[arm]
        record = TicketRecord(policy=self.plan.policy, policy_fingerprint=self.plan.policy_fingerprint,
                              extra={"session_search": {"successes": won, "episodes": episodes}})
        return Ticket(self._store.noise(arm), record)

    def _save_verdict(self, complete: SessionVerdict | None) -> None:
        if complete is None:
            remove_verdict(self.path.parent)
        else:
            save_verdict(self.path.parent, self.name, self.plan, complete, self._store.search_record(),
                         self._store.finalists())

    def _check_planned(self, episode: int) -> None:
        if not 0 <= episode < self.plan.episodes:
            raise UserError(f"episode {episode} is not in the plan (episodes 0 to {self.plan.episodes - 1})")

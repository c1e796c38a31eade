"""A real-robot search session scored by a person, kept in SQLite (`session.sqlite`).

Every score is written the moment it is entered; only the due episode (the first unscored one)
can be scored, and what is planned next is a function of the seed and the scores (`race`), so a
restart resumes where it stopped. The files beside the store (`derived`: the finalists'
tickets, and once complete summary.json and verdict.png) are brought in line with it whenever
the session is opened or asked what is due.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from goldenticket.errors import UserError
from goldenticket.session.derived import remove_verdict, save_tickets, save_verdict
from goldenticket.session.episode import NextEpisode
from goldenticket.session.race import BASE, Plan, Race, candidates, next_episodes, race
from goldenticket.session.verdict import (
    Confirmed,
    Pairs,
    SessionVerdict,
    confirm_pairs,
    fixed_verdict,
    sequential_test,
    sequential_verdict,
)
from goldenticket.stats import Sequential
from goldenticket.tickets import Ticket, TicketRecord

FILE = "session.sqlite"
_SCHEMA = """
CREATE TABLE plan (id INTEGER PRIMARY KEY CHECK (id = 0), value TEXT NOT NULL);
CREATE TABLE arms (arm TEXT PRIMARY KEY, noise BLOB);
CREATE TABLE episodes (
    episode INTEGER PRIMARY KEY, phase TEXT NOT NULL, arm TEXT NOT NULL,
    success INTEGER, note TEXT, scene TEXT, scored_at REAL, entry INTEGER UNIQUE
);
"""


class ScoreConflict(UserError):
    """A score for an episode scored already or not yet due, or an undo of an episode that is
    not the last one scored; `details` names the due or the last scored episode."""

    def __init__(self, message: str, **details: int | None):
        super().__init__(message)
        self.details = details


class StoreLost(UserError):
    """session.sqlite was deleted or replaced while open: nothing more could be saved."""


class Session:
    """One session folder. Every method is a short transaction, so several processes (a server,
    a terminal scorer, the robot's Python loop) can share it."""

    def __init__(self, folder: str | Path):
        self.path = Path(folder) / FILE
        if not self.path.is_file():
            raise UserError(f"{folder}: no session here (create one with `goldenticket session new`)")
        self._file = _identity(self.path)  # before connecting: a file swapped meanwhile is refused
        self._con = _connect(self.path)
        try:
            fields = json.loads(self._one("SELECT value FROM plan")[0])
            fields = {"stopping": "fixed", "alpha": 0.05} | fields  # planned before sequential stopping
            self.plan = Plan(**{**fields, "noise_shape": tuple(fields["noise_shape"])})
            _number_old_scores(self._con)
        except (sqlite3.DatabaseError, TypeError, ValueError, KeyError):
            raise UserError(f"{self.path}: not a goldenticket session, or damaged") from None
        self.name = self.path.parent.resolve().name
        self._refresh()

    @classmethod
    def new(cls, folder: str | Path, plan: Plan) -> Session:
        """Plan the first search round and write it; refuses a folder that holds a session already."""
        path = Path(folder) / FILE
        if path.exists():
            raise UserError(f"{path} exists: a session is already planned there (serve or score it)")
        path.parent.mkdir(parents=True, exist_ok=True)
        arms, order = candidates(plan)
        con = _connect(path)
        with con:
            con.executescript(_SCHEMA)
            con.execute("INSERT INTO plan VALUES (0, ?)", (json.dumps(plan.__dict__),))
            con.executemany("INSERT INTO arms VALUES (?, ?)", [(a, n.tobytes()) for a, n in arms.items()])
            con.execute("INSERT INTO arms VALUES (?, NULL)", (BASE,))
            con.executemany("INSERT INTO episodes (episode, phase, arm) VALUES (?, 'search', ?)",
                            list(enumerate(order)))
        con.close()
        return cls(folder)

    def next(self) -> NextEpisode | None:
        """The due episode (planning the next round or the confirm phase once the last is scored),
        or None when the session is complete."""
        due = self._refresh()["due"]
        return None if due is None else self.episode(due)

    def episode(self, episode: int) -> NextEpisode:
        """What the robot runs for one planned episode."""
        arm = self._one("SELECT arm FROM episodes WHERE episode = ?", (episode,))[0]
        if arm == BASE:
            return NextEpisode(episode, BASE, None, [self.plan.seed, episode], self.plan.noise_shape)
        return NextEpisode(episode, arm, self._noise(arm), None, self.plan.noise_shape)

    def score(self, episode: int, success: bool, note: str = "", scene: str | None = None) -> None:
        """Record the due episode's outcome, committed at once; ScoreConflict (naming the due
        episode) for any other."""
        self._check_planned(episode)
        self._plan_next_if_due()
        with self._transaction() as con:
            due = self._due()
            if episode != due:
                scored = self._one("SELECT success IS NOT NULL FROM episodes WHERE episode = ?", (episode,))
                why = "scored already" if scored and scored[0] else "not due"
                then = "the session is complete" if due is None else f"the due episode is {due}"
                raise ScoreConflict(f"episode {episode} is {why}; {then}", due=due)
            con.execute("UPDATE episodes SET success = ?, note = ?, scene = ?, scored_at = ?, "
                        "entry = (SELECT COALESCE(MAX(entry), 0) + 1 FROM episodes) WHERE episode = ?",
                        (int(bool(success)), note, scene, time.time(), episode))

    def undo(self, episode: int) -> None:
        """Unscore `episode`, which must be the last score entered (and drop the unstarted rounds
        planned from it); ScoreConflict (naming the last scored episode) otherwise."""
        self._check_planned(episode)
        with self._transaction() as con:
            last = self._last_scored()
            if episode != last:
                raise ScoreConflict(f"episode {episode} is not the last one scored; that is {last}",
                                    last_scored=last)
            later = [end for end in self._race().ends if end > episode]  # rounds planned from its score
            con.execute("UPDATE episodes SET success = NULL, note = NULL, scene = NULL, scored_at = NULL, "
                        "entry = NULL WHERE episode = ?", (episode,))
            if later:
                con.execute("DELETE FROM episodes WHERE episode >= ?", (later[0],))

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
        cols = ("episode", "phase", "arm", "success", "note", "scene", "scored_at", "entry")
        return [dict(zip(cols, r, strict=True)) for r in
                self._con.execute(f"SELECT {', '.join(cols)} FROM episodes ORDER BY episode")]

    def _refresh(self) -> dict:
        """Plan the next round or the confirm phase if due, bring the derived files in line with
        the store, and return the status."""
        self._check_store()
        self._plan_next_if_due()
        save_tickets(self.path.parent / "tickets", self._finalists(), self._ticket)
        status = self._status()
        self._save_verdict(status.get("verdict"))
        return status

    def _status(self) -> dict:
        scored, planned = self._one("SELECT COUNT(success), COUNT(*) FROM episodes")
        due, confirm = self._due(), self._confirm_start()
        status = {"scored": scored, "total": self.plan.episodes, "planned": planned,
                  "phase": "search" if confirm is None else "confirm", "due": due,
                  "last_scored": self._last_scored(), "stopping": self.plan.stopping,
                  "stage": self._stage(due)}
        if due is None and confirm is not None:
            status["verdict"] = self._verdict()
        return status

    def _stage(self, due: int | None) -> str:
        """What the due episode is, in words for the operator (never its arm)."""
        if due is None:
            return "complete"
        confirm = self._confirm_start()
        if confirm is None and self.plan.stopping == "fixed":
            return "search phase"
        if confirm is None:
            search, ends = self._search(), self._race().ends
            round_ = sum(end <= due for end in ends)
            left = len({arm for arm, _ in search[ends[round_ - 1] if round_ else 0:ends[round_]]})
            return f"search phase, round {round_ + 1}, {left} tickets left"
        if self.plan.stopping == "fixed":
            return "confirm phase"
        pair, run = divmod(due - confirm, 2)
        scene = "the same scene as run 1" if run else "set up a new scene"
        return f"confirm phase, pair {pair + 1} of at most {self.plan.confirm}, run {run + 1} of 2: {scene}"

    def _verdict(self) -> SessionVerdict:
        if self.plan.stopping == "fixed":
            return fixed_verdict(self.plan, self._confirmed())
        scored, stopped_at = self._one("SELECT COUNT(success), MAX(scored_at) FROM episodes")
        return sequential_verdict(self.plan, self._pairs(), scored, stopped_at)

    def _test(self) -> Sequential | None:
        """The sequential sign test on the confirm pairs scored so far; None for a fixed session."""
        return None if self.plan.stopping == "fixed" else sequential_test(self.plan, self._pairs())

    def _pairs(self) -> Pairs:
        return confirm_pairs(self._confirmed(), next(iter(self._finalists()), None))

    def _confirmed(self) -> Confirmed:
        """The scored confirm episodes' arm, outcome and scene, in order."""
        return [(arm, bool(success), scene) for arm, success, scene in self._con.execute(
            "SELECT arm, success, scene FROM episodes WHERE phase = 'confirm' AND success IS NOT NULL "
            "ORDER BY episode")]

    def _plan_next_if_due(self) -> None:
        if not self._round_due():
            return
        with self._transaction() as con:
            if not self._round_due():  # another process planned it meanwhile
                return
            planned, (phase, arms) = len(self._search()), next_episodes(self.plan, self._race())
            con.executemany("INSERT INTO episodes (episode, phase, arm) VALUES (?, ?, ?)",
                            [(planned + i, phase, a) for i, a in enumerate(arms)])

    def _round_due(self) -> bool:
        """Whether every planned episode is scored and the confirm phase not planned yet."""
        scored, planned, confirm = self._one("SELECT COUNT(success), COUNT(*), SUM(phase = 'confirm') "
                                             "FROM episodes")
        return scored == planned and not confirm

    def _race(self) -> Race:
        query = "SELECT arm FROM arms WHERE arm != ? ORDER BY rowid"
        return race(self.plan, [a for (a,) in self._con.execute(query, (BASE,))], self._search())

    def _search(self) -> list[tuple[str, bool | None]]:
        """Every planned search episode's arm and outcome (None: not scored yet), in order."""
        return [(arm, None if success is None else bool(success)) for arm, success in self._con.execute(
            "SELECT arm, success FROM episodes WHERE phase = 'search' ORDER BY episode")]

    def _confirm_start(self) -> int | None:
        """The first confirm episode; None before the confirm phase is planned."""
        return self._one("SELECT MIN(episode) FROM episodes WHERE phase = 'confirm'")[0]

    def _search_record(self) -> dict[str, tuple[int, int]]:
        """Search successes and scored episodes per candidate, in candidate order."""
        return {arm: (int(won or 0), n) for arm, won, n in self._con.execute(
            "SELECT arms.arm, SUM(success), COUNT(success) FROM arms JOIN episodes USING (arm) "
            "WHERE phase = 'search' GROUP BY arms.arm ORDER BY arms.rowid")}

    def _finalists(self) -> list[str]:
        return [a for (a,) in self._con.execute("SELECT DISTINCT arm FROM episodes WHERE phase = 'confirm' "
                                                "AND arm != ? ORDER BY arm", (BASE,))]

    def _ticket(self, arm: str) -> Ticket:
        """A finalist as a ticket for the policy, with its search record."""
        won, episodes = self._search_record()[arm]
        record = TicketRecord(policy=self.plan.policy, policy_fingerprint=self.plan.policy_fingerprint,
                              extra={"session_search": {"successes": won, "episodes": episodes}})
        return Ticket(self._noise(arm), record)

    def _save_verdict(self, complete: SessionVerdict | None) -> None:
        if complete is None:
            remove_verdict(self.path.parent)
        else:
            save_verdict(self.path.parent, self.name, self.plan, complete, self._search_record(),
                         self._finalists())

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """One write transaction, locked from its first read (BEGIN IMMEDIATE): no other process
        writes between what it reads and what it writes."""
        self._check_store()
        self._con.execute("BEGIN IMMEDIATE")
        with self._con:
            yield self._con

    def _check_store(self) -> None:
        """StoreLost if session.sqlite is no longer the file opened: scores would vanish with it."""
        try:
            same = _identity(self.path) == self._file
        except OSError:
            same = False
        if not same:
            raise StoreLost(f"{self.path} was deleted or replaced while in use: scores can no longer be "
                            "saved (put the file back, or restart from a copy)")

    def _check_planned(self, episode: int) -> None:
        if not 0 <= episode < self.plan.episodes:
            raise UserError(f"episode {episode} is not in the plan (episodes 0 to {self.plan.episodes - 1})")

    def _due(self) -> int | None:
        """The first unscored episode, unless the sequential test has decided."""
        due = self._one("SELECT MIN(episode) FROM episodes WHERE success IS NULL")[0]
        if due is not None and self._confirm_start() is not None and (test := self._test()) and test.decision:
            return None
        return due

    def _last_scored(self) -> int | None:
        row = self._one("SELECT episode FROM episodes WHERE entry IS NOT NULL ORDER BY entry DESC LIMIT 1")
        return None if row is None else row[0]

    def _noise(self, arm: str) -> np.ndarray:
        blob = self._one("SELECT noise FROM arms WHERE arm = ?", (arm,))[0]
        return np.frombuffer(blob, dtype=np.float32).reshape(self.plan.noise_shape).copy()

    def _one(self, sql: str, args: tuple = ()):
        return self._con.execute(sql, args).fetchone()


def _identity(path: Path) -> tuple[int, int]:
    info = os.stat(path)
    return info.st_dev, info.st_ino


def _number_old_scores(con: sqlite3.Connection) -> None:
    """A session stored before scores had an entry number gets one: its scores numbered in the
    order they were entered (by time, then episode), so undo takes back the last of them."""
    if "entry" in {row[1] for row in con.execute("PRAGMA table_info(episodes)")}:
        return
    with con:
        con.execute("ALTER TABLE episodes ADD COLUMN entry INTEGER")
        con.execute("CREATE UNIQUE INDEX episodes_entry ON episodes (entry)")
        scored = con.execute("SELECT episode FROM episodes WHERE success IS NOT NULL "
                             "ORDER BY scored_at, episode").fetchall()
        con.executemany("UPDATE episodes SET entry = ? WHERE episode = ?",
                        [(n, episode) for n, (episode,) in enumerate(scored, 1)])


def _connect(path: Path) -> sqlite3.Connection:
    try:
        con = sqlite3.connect(path, timeout=30, check_same_thread=False)
        con.execute("PRAGMA journal_mode = WAL")
        con.execute("PRAGMA synchronous = FULL")  # a score survives kill -9 and power loss
    except sqlite3.Error as e:
        raise UserError(f"{path}: cannot open the session ({e})") from None
    return con

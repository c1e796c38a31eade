"""A session's SQLite file (`session.sqlite`): the plan, the candidate tickets' noise, and one row
per planned episode with its arm, score, note, scene id, time and place in the order of entry.

Rows in and out, nothing decided here: what is due is `planner`'s. Every write is one transaction
locked from its first read (BEGIN IMMEDIATE), on a connection in WAL mode with synchronous FULL,
so several processes can share the file and `kill -9` loses nothing committed.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from goldenticket.errors import UserError
from goldenticket.session.race import BASE, Plan, is_candidate
from goldenticket.session.verdict import Confirmed

FILE = "session.sqlite"
_SCHEMA = """
CREATE TABLE plan (id INTEGER PRIMARY KEY CHECK (id = 0), value TEXT NOT NULL);
CREATE TABLE arms (arm TEXT PRIMARY KEY, noise BLOB);
CREATE TABLE episodes (
    episode INTEGER PRIMARY KEY, phase TEXT NOT NULL, arm TEXT NOT NULL,
    success INTEGER, note TEXT, scene TEXT, scored_at REAL, entry INTEGER UNIQUE
);
"""
_COLUMNS = ("episode", "phase", "arm", "success", "note", "scene", "scored_at", "entry")


class StoreLost(UserError):
    """session.sqlite was deleted or replaced while open: nothing more could be saved."""


class Store:
    """One open session.sqlite: its `plan`, its `candidates` (ticket ids, in their order) and its
    episodes. It refuses to go on once the file is no longer the one it opened."""

    def __init__(self, folder: str | Path):
        self.path = Path(folder) / FILE
        if not self.path.is_file():
            raise UserError(f"{folder}: no session here (create one with `goldenticket session new`)")
        self._file = _identity(self.path)  # before connecting: a file swapped meanwhile is refused
        self.con = _connect(self.path)
        try:
            self.plan = _read_plan(self.con)
            _number_old_scores(self.con)
            self.candidates = _checked_candidates(self.con, self.plan)
        except (sqlite3.DatabaseError, TypeError, ValueError, KeyError):
            raise UserError(f"{self.path}: not a goldenticket session, or damaged") from None

    @staticmethod
    def create(folder: str | Path, plan: Plan, noise: dict[str, np.ndarray], first_round: list[str]) -> None:
        """Write a new session.sqlite in `folder`: the plan, the candidates' noise by ticket id, the
        base, and the first round's search episodes (their arms, in order)."""
        path = Path(folder) / FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        con = _connect(path)
        with con:
            con.executescript(_SCHEMA)
            con.execute("INSERT INTO plan VALUES (0, ?)", (json.dumps(plan.__dict__),))
            con.executemany("INSERT INTO arms VALUES (?, ?)", [(a, n.tobytes()) for a, n in noise.items()])
            con.execute("INSERT INTO arms VALUES (?, NULL)", (BASE,))
            _insert_episodes(con, 0, "search", first_round)
        con.close()

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """One write transaction, locked from its first read (BEGIN IMMEDIATE): no other process
        writes between what it reads and what it writes."""
        self.check()
        self.con.execute("BEGIN IMMEDIATE")
        with self.con:
            yield

    def check(self) -> None:
        """StoreLost if session.sqlite is no longer the file opened: scores would vanish with it."""
        try:
            same = _identity(self.path) == self._file
        except OSError:
            same = False
        if not same:
            raise StoreLost(f"{self.path} was deleted or replaced while in use: scores can no longer be "
                            "saved (put the file back, or restart from a copy)")

    def arm(self, episode: int) -> str:
        return self._one("SELECT arm FROM episodes WHERE episode = ?", (episode,))[0]

    def noise(self, arm: str) -> np.ndarray:
        """A candidate's (H, A) noise."""
        blob = self._one("SELECT noise FROM arms WHERE arm = ?", (arm,))[0]
        return np.frombuffer(blob, dtype=np.float32).reshape(self.plan.noise_shape).copy()

    def tally(self) -> tuple[int, int, float | None]:
        """Episodes scored, episodes planned, and when the last score was entered."""
        return self._one("SELECT COUNT(success), COUNT(*), MAX(scored_at) FROM episodes")

    def first_unscored(self) -> int | None:
        return self._one("SELECT MIN(episode) FROM episodes WHERE success IS NULL")[0]

    def is_scored(self, episode: int) -> bool:
        row = self._one("SELECT success IS NOT NULL FROM episodes WHERE episode = ?", (episode,))
        return bool(row and row[0])

    def confirm_start(self) -> int | None:
        """The first confirm episode; None before the confirm phase is planned."""
        return self._one("SELECT MIN(episode) FROM episodes WHERE phase = 'confirm'")[0]

    def last_scored(self) -> int | None:
        """The episode whose score was entered last (by entry sequence, not by the clock)."""
        row = self._one("SELECT episode FROM episodes WHERE entry IS NOT NULL ORDER BY entry DESC LIMIT 1")
        return None if row is None else row[0]

    def search(self) -> list[tuple[str, bool | None]]:
        """Every planned search episode's arm and outcome (None: not scored yet), in order."""
        return [(arm, None if success is None else bool(success)) for arm, success in self.con.execute(
            "SELECT arm, success FROM episodes WHERE phase = 'search' ORDER BY episode")]

    def confirmed(self) -> Confirmed:
        """The scored confirm episodes' arm, outcome and scene, in order."""
        return [(arm, bool(success), scene) for arm, success, scene in self.con.execute(
            "SELECT arm, success, scene FROM episodes WHERE phase = 'confirm' AND success IS NOT NULL "
            "ORDER BY episode")]

    def finalists(self) -> list[str]:
        """The candidates planned in the confirm phase."""
        return [a for (a,) in self.con.execute("SELECT DISTINCT arm FROM episodes WHERE phase = 'confirm' "
                                               "AND arm != ? ORDER BY arm", (BASE,))]

    def search_record(self) -> dict[str, tuple[int, int]]:
        """Search successes and scored episodes per candidate, in candidate order."""
        return {arm: (int(won or 0), n) for arm, won, n in self.con.execute(
            "SELECT arms.arm, SUM(success), COUNT(success) FROM arms JOIN episodes USING (arm) "
            "WHERE phase = 'search' GROUP BY arms.arm ORDER BY arms.rowid")}

    def rows(self) -> list[dict]:
        """Every planned episode's row, in order."""
        return [dict(zip(_COLUMNS, r, strict=True)) for r in
                self.con.execute(f"SELECT {', '.join(_COLUMNS)} FROM episodes ORDER BY episode")]

    def plan_episodes(self, first: int, phase: str, arms: list[str]) -> None:
        """Plan episodes `first`, `first` + 1, ... of `phase` with `arms`, in order."""
        _insert_episodes(self.con, first, phase, arms)

    def enter_score(self, episode: int, success: bool, note: str, scene: str | None) -> None:
        """Score `episode` now, next in the order of entry."""
        self.con.execute("UPDATE episodes SET success = ?, note = ?, scene = ?, scored_at = ?, "
                         "entry = (SELECT COALESCE(MAX(entry), 0) + 1 FROM episodes) WHERE episode = ?",
                         (int(bool(success)), note, scene, time.time(), episode))

    def unscore(self, episode: int) -> None:
        self.con.execute("UPDATE episodes SET success = NULL, note = NULL, scene = NULL, scored_at = NULL, "
                         "entry = NULL WHERE episode = ?", (episode,))

    def drop_from(self, episode: int) -> None:
        """Unplan `episode` and every episode after it."""
        self.con.execute("DELETE FROM episodes WHERE episode >= ?", (episode,))

    def _one(self, sql: str, args: tuple = ()):
        return self.con.execute(sql, args).fetchone()


def _identity(path: Path) -> tuple[int, int]:
    info = os.stat(path)
    return info.st_dev, info.st_ino


def _read_plan(con: sqlite3.Connection) -> Plan:
    fields = json.loads(con.execute("SELECT value FROM plan").fetchone()[0])
    fields = {"stopping": "fixed", "alpha": 0.05} | fields  # planned before sequential stopping
    return Plan(**{**fields, "noise_shape": tuple(fields["noise_shape"])})


def _checked_candidates(con: sqlite3.Connection, plan: Plan) -> list[str]:
    """The candidates' names, in their order. ValueError unless every arm stored is the base (no
    noise) or a candidate named as `race.candidates` names one, with (H, A) float32 noise, and
    every episode's arm is one of them: a name read from the file becomes a file name in tickets/."""
    noise = ("blob", 4 * math.prod(plan.noise_shape))

    def fits(arm, stored: tuple) -> bool:
        return stored == ("null", None) if arm == BASE else is_candidate(arm) and stored == noise

    arms = {arm: (kind, size) for arm, kind, size in con.execute(
        "SELECT arm, typeof(noise), length(noise) FROM arms ORDER BY rowid")}
    planned = {arm for (arm,) in con.execute("SELECT DISTINCT arm FROM episodes")}
    if not planned <= arms.keys() or not all(fits(arm, stored) for arm, stored in arms.items()):
        raise ValueError("an arm that is neither the base nor a candidate ticket")
    return [arm for arm in arms if arm != BASE]


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


def _insert_episodes(con: sqlite3.Connection, first: int, phase: str, arms: list[str]) -> None:
    con.executemany("INSERT INTO episodes (episode, phase, arm) VALUES (?, ?, ?)",
                    [(first + i, phase, arm) for i, arm in enumerate(arms)])


def _connect(path: Path) -> sqlite3.Connection:
    try:
        con = sqlite3.connect(path, timeout=30, check_same_thread=False)
        con.execute("PRAGMA journal_mode = WAL")
        con.execute("PRAGMA synchronous = FULL")  # a score survives kill -9 and power loss
    except sqlite3.Error as e:
        raise UserError(f"{path}: cannot open the session ({e})") from None
    return con

"""The run store: one SQLite file per run holding its config and every episode, for resuming."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.files import check_target

_VERSION = 1
_SCHEMA = """
CREATE TABLE config (id INTEGER PRIMARY KEY CHECK (id = 0), value TEXT NOT NULL);
CREATE TABLE episodes (
    ticket_id TEXT NOT NULL, task TEXT NOT NULL, seed INTEGER NOT NULL, seed_set TEXT NOT NULL,
    success INTEGER NOT NULL, ret REAL NOT NULL, length INTEGER NOT NULL, wall_time REAL NOT NULL,
    cause TEXT,
    PRIMARY KEY (ticket_id, task, seed, seed_set)
);
"""
# Added since the first stores; opening an older store adds them.
_CAUSE = "ALTER TABLE episodes ADD COLUMN cause TEXT"
_INITIAL_STATES = """CREATE TABLE IF NOT EXISTS initial_states (
    task TEXT NOT NULL, seed INTEGER NOT NULL, digest TEXT NOT NULL, PRIMARY KEY (task, seed)
)"""
_COLUMNS = "ticket_id, task, seed, seed_set, success, ret, length, wall_time, cause"
_SIBLINGS = ("-journal", "-wal", "-shm")  # files SQLite keeps beside the store


@dataclass(frozen=True)
class EpisodeRow:
    """One finished rollout. ticket_id is a ticket's id, "base" (Gaussian noise) or "zero"."""

    ticket_id: str
    task: str
    seed: int
    seed_set: str  # "search" or "heldout"
    success: bool
    ret: float  # episode return
    length: int
    wall_time: float
    cause: str | None = None  # why a failed episode ended early (rollout.NONFINITE), else None


def _values(r: EpisodeRow) -> tuple:
    """Plain Python values for SQLite (rollouts often yield numpy scalars)."""
    return (
        r.ticket_id,
        r.task,
        int(r.seed),
        r.seed_set,
        int(bool(r.success)),
        float(r.ret),
        int(r.length),
        float(r.wall_time),
        r.cause,
    )


def _first_problem(check: str) -> str:
    """The first problem in SQLite's quick_check report (a heading, then a line per problem)."""
    problems = [line for line in check.splitlines() if line.strip() and not line.startswith("***")]
    return problems[0] if problems else check


class RunStore:
    """SQLite-backed record of a run. Re-recording an episode replaces it, so resuming is safe.

    Several processes may share one store: writes are transactions that wait for each other.
    Every SQLite or file-system failure becomes a one-line UserError; what was committed stays.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        for file in (self.path, *(self.path.with_name(self.path.name + s) for s in _SIBLINGS)):
            check_target(file, "move it away: a run store and its journal are regular files")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._con = sqlite3.connect(self.path, timeout=60, isolation_level=None)
        except (OSError, sqlite3.Error) as e:
            raise UserError(f"{self.path}: cannot open run store ({e})") from None
        try:
            with self._transaction():
                problem = self._schema_problem()
        except UserError:
            self._con.close()
            raise
        if problem:
            self._con.close()
            raise UserError(f"{self.path}: {problem}")

    @contextmanager
    def _transaction(self, mode: str = "IMMEDIATE") -> Iterator[sqlite3.Connection]:
        """BEGIN ... COMMIT (ROLLBACK on error), SQLite errors as UserError; IMMEDIATE takes the
        write lock at once, DEFERRED (for reads) only when needed."""
        try:
            self._con.execute(f"BEGIN {mode}")
            try:
                yield self._con
                self._con.execute("COMMIT")
            except BaseException:
                if self._con.in_transaction:  # SQLite may have rolled back already (disk full)
                    self._con.execute("ROLLBACK")
                raise
        except sqlite3.DatabaseError as e:
            if getattr(e, "sqlite_errorname", "") in ("SQLITE_CORRUPT", "SQLITE_NOTADB"):
                raise self._damaged(str(e)) from None
            failed = f"{self.path}: run store failed ({e}); what was recorded before is kept"
            raise UserError(failed) from None

    def _damaged(self, reason: str) -> UserError:
        """The one line for a file that is not a sound run store."""
        return UserError(f"{self.path}: damaged run store ({reason}); move it away to start again")

    def _schema_problem(self) -> str | None:
        """Create the schema in a new file; say what is wrong with a file that is not a store
        (UserError for a damaged store)."""
        version = self._con.execute("PRAGMA user_version").fetchone()[0]
        if version == _VERSION:
            check = self._con.execute("PRAGMA quick_check").fetchone()[0]
            if check != "ok":
                raise self._damaged(_first_problem(check))
            if "cause" not in {row[1] for row in self._con.execute("PRAGMA table_info(episodes)")}:
                self._con.execute(_CAUSE)
            self._con.execute(_INITIAL_STATES)
            return None
        tables = self._con.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if version != 0 or tables:
            return "SQLite file is not a goldenticket run store"
        for statement in [*_SCHEMA.split(";")[:-1], _INITIAL_STATES, f"PRAGMA user_version = {_VERSION}"]:
            self._con.execute(statement)  # not executescript: it would commit mid-transaction
        return None

    def close(self) -> None:
        self._con.close()

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def claim_config(self, config: dict) -> bool:
        """Store `config` in a store that has none; True if the stored config now equals it.
        One transaction, so two processes starting on one store agree on its config."""
        with self._transaction() as con:
            row = con.execute("SELECT value FROM config").fetchone()
            if row is None:
                con.execute("INSERT INTO config VALUES (0, ?)", (json.dumps(config, sort_keys=True),))
                return True
        try:
            stored = json.loads(row[0])
        except (TypeError, ValueError, RecursionError):
            raise self._damaged("its config is not JSON") from None
        return stored == json.loads(json.dumps(config))

    def record(self, rows: Iterable[EpisodeRow]) -> None:
        """Insert episodes in one transaction; an episode already recorded is replaced."""
        with self._transaction() as con:
            con.executemany(
                f"INSERT OR REPLACE INTO episodes ({_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (_values(r) for r in rows),
            )

    def first_digests(self, task: str, digests: Iterable[tuple[int, str]]) -> list[str]:
        """For each (seed, initial-state digest) of `task`, in order: the digest first recorded for
        that seed, this one if none was; in one transaction, so every process of a run compares
        with the same record."""
        with self._transaction() as con:
            recorded = []
            for seed, digest in digests:
                key = (task, int(seed))
                con.execute("INSERT OR IGNORE INTO initial_states VALUES (?, ?, ?)", (*key, digest))
                recorded += con.execute("SELECT digest FROM initial_states WHERE task = ? AND seed = ?",
                                        key).fetchone()
            return recorded

    def episodes(
        self, *, ticket_id: str | None = None, seed_set: str | None = None, task: str | None = None
    ) -> list[EpisodeRow]:
        """Episodes matching every given filter, ordered by ticket, task, seed set, seed."""
        filters = {"ticket_id": ticket_id, "seed_set": seed_set, "task": task}
        used = {k: v for k, v in filters.items() if v is not None}
        where = " AND ".join(f"{k} = :{k}" for k in used) or "1"
        query = (
            f"SELECT {_COLUMNS} FROM episodes WHERE {where} "
            "ORDER BY ticket_id, task, seed_set, seed"
        )
        with self._transaction("DEFERRED") as con:
            rows = con.execute(query, used).fetchall()
        return [self._row(v) for v in rows]

    def _row(self, values: tuple) -> EpisodeRow:
        """A stored episode; UserError if a number in it is not a number (a damaged file)."""
        row = EpisodeRow(*values)
        for name in ("seed", "success", "ret", "length", "wall_time"):
            value = getattr(row, name)
            if not isinstance(value, int | float):
                raise self._damaged(f"episode {row.ticket_id} seed {row.seed!r} has a non-numeric {name} "
                                    f"({value!r:.40})")
        return replace(row, success=bool(row.success))

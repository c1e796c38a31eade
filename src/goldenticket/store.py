"""The run store: one SQLite file per run holding its config and every episode, for resuming."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from goldenticket.errors import UserError

_VERSION = 1
_SCHEMA = """
CREATE TABLE config (id INTEGER PRIMARY KEY CHECK (id = 0), value TEXT NOT NULL);
CREATE TABLE episodes (
    ticket_id TEXT NOT NULL, task TEXT NOT NULL, seed INTEGER NOT NULL, seed_set TEXT NOT NULL,
    success INTEGER NOT NULL, ret REAL NOT NULL, length INTEGER NOT NULL, wall_time REAL NOT NULL,
    PRIMARY KEY (ticket_id, task, seed, seed_set)
);
"""
_COLUMNS = "ticket_id, task, seed, seed_set, success, ret, length, wall_time"


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
    )


def _row(values: tuple) -> EpisodeRow:
    ticket_id, task, seed, seed_set, success, ret, length, wall_time = values
    return EpisodeRow(ticket_id, task, seed, seed_set, bool(success), ret, length, wall_time)


class RunStore:
    """SQLite-backed record of a run. Re-recording an episode replaces it, so resuming is safe."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._con = sqlite3.connect(self.path)
        except sqlite3.Error as e:
            raise UserError(f"{self.path}: cannot open run store ({e})") from None
        try:
            problem = self._schema_problem()
        except sqlite3.DatabaseError as e:
            problem = f"not a usable SQLite run store ({e})"
        if problem:
            self._con.close()
            raise UserError(f"{self.path}: {problem}")

    def _schema_problem(self) -> str | None:
        """Create the schema in a new file; say what is wrong with a file that is not a store."""
        version = self._con.execute("PRAGMA user_version").fetchone()[0]
        if version == _VERSION:
            return None
        tables = self._con.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if version != 0 or tables:
            return "SQLite file is not a goldenticket run store"
        self._con.executescript(f"BEGIN; {_SCHEMA} PRAGMA user_version = {_VERSION}; COMMIT;")
        return None

    def close(self) -> None:
        self._con.close()

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def set_config(self, config: dict) -> None:
        """Store the run's config (JSON), replacing any earlier one."""
        with self._con:
            self._con.execute(
                "INSERT OR REPLACE INTO config VALUES (0, ?)", (json.dumps(config, sort_keys=True),)
            )

    def get_config(self) -> dict | None:
        row = self._con.execute("SELECT value FROM config").fetchone()
        return None if row is None else json.loads(row[0])

    def record(self, rows: Iterable[EpisodeRow]) -> None:
        """Insert episodes in one transaction; an episode already recorded is replaced."""
        with self._con:
            self._con.executemany(
                f"INSERT OR REPLACE INTO episodes ({_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (_values(r) for r in rows),
            )

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
        return [_row(v) for v in self._con.execute(query, used)]

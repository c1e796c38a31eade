"""A real-robot search session: the paper's protocol, scored by a person, kept in SQLite.

Search: N random candidate tickets x K episodes, in a shuffled order. Confirm: the two
candidates with the most search successes (ties: the earlier candidate) and the base policy,
M episodes each, interleaved in a shuffled order so the operator cannot tell which arm runs.
Every score is written the moment it is entered; only the due episode (the first unscored one)
can be scored, so a restart resumes where it stopped. The files beside the store (the
finalists' tickets, and once complete summary.json and verdict.png) are derived from it and
brought in line with it whenever the session is opened or asked what is due.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.stats import fisher_exact

from goldenticket.errors import UserError
from goldenticket.files import write_atomic
from goldenticket.stats import Rate, holm_adjust, paired_exact_test
from goldenticket.tickets import Ticket

FILE = "session.sqlite"
BASE = "base"
MAX_EPISODES = 100_000
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


@dataclass(frozen=True)
class Plan:
    policy: str
    policy_fingerprint: str
    noise_shape: tuple[int, int]
    tickets: int
    episodes_per_ticket: int
    confirm: int
    seed: int

    def __post_init__(self) -> None:
        for name, value, least in (("tickets", self.tickets, 2), ("confirm", self.confirm, 1),
                                   ("episodes-per-ticket", self.episodes_per_ticket, 1)):
            if value < least:
                why = " (the confirm phase takes the top 2)" if name == "tickets" else ""
                raise UserError(f"--{name} must be at least {least}{why}, got {value}")
        if self.episodes > MAX_EPISODES:
            raise UserError(f"a session plans at most {MAX_EPISODES} episodes (tickets x episodes-per-ticket "
                            f"+ 3 x confirm), got {self.episodes}")

    @property
    def episodes(self) -> int:
        """Every episode of the session: N x K search, 3 x M confirm."""
        return self.tickets * self.episodes_per_ticket + 3 * self.confirm


@dataclass(frozen=True)
class NextEpisode:
    """What the robot runs next: a ticket's noise for every policy call, or, for the base arm
    (`noise` None), fresh N(0, I) noise per call from `numpy.random.default_rng(gaussian_seed)`."""

    episode: int
    ticket_id: str
    noise: np.ndarray | None
    gaussian_seed: list[int] | None

    def to_json(self) -> dict:
        noise = None if self.noise is None else self.noise.tolist()
        return {"episode": self.episode, "ticket_id": self.ticket_id, "noise": noise,
                "gaussian_seed": self.gaussian_seed}


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
        except (sqlite3.DatabaseError, TypeError):
            raise UserError(f"{self.path}: not a goldenticket session, or damaged") from None
        self.plan = Plan(**{**fields, "noise_shape": tuple(fields["noise_shape"])})
        self.name = self.path.parent.resolve().name
        self._refresh()

    @classmethod
    def new(cls, folder: str | Path, plan: Plan) -> Session:
        """Plan the search phase and write it; refuses a folder that holds a session already."""
        path = Path(folder) / FILE
        if path.exists():
            raise UserError(f"{path} exists: a session is already planned there (serve or score it)")
        path.parent.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng([plan.seed, 0])
        candidates = rng.standard_normal((plan.tickets, *plan.noise_shape), dtype=np.float32)
        arms = {_ticket_id(noise, plan): noise for noise in candidates}
        order = [arm for arm in arms for _ in range(plan.episodes_per_ticket)]
        rng.shuffle(order)
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
        """The due episode (planning the confirm phase once search is scored), or None when done."""
        due = self._refresh()["due"]
        return None if due is None else self.episode(due)

    def episode(self, episode: int) -> NextEpisode:
        """What the robot runs for one planned episode."""
        arm = self._one("SELECT arm FROM episodes WHERE episode = ?", (episode,))[0]
        if arm == BASE:
            return NextEpisode(episode, BASE, None, [self.plan.seed, episode])
        return NextEpisode(episode, arm, self._noise(arm), None)

    def score(self, episode: int, success: bool, note: str = "", scene: str | None = None) -> None:
        """Record the due episode's outcome, committed at once; ScoreConflict (naming the due
        episode) for any other."""
        self._check_planned(episode)
        self._plan_confirm_if_due()
        with self._transaction() as con:
            due = self._due()
            if episode != due:
                scored = self._one("SELECT success IS NOT NULL FROM episodes WHERE episode = ?", (episode,))
                why = "scored already" if scored and scored[0] else "not due"
                raise ScoreConflict(f"episode {episode} is {why}; the due episode is {due}", due=due)
            con.execute("UPDATE episodes SET success = ?, note = ?, scene = ?, scored_at = ?, "
                        "entry = (SELECT COALESCE(MAX(entry), 0) + 1 FROM episodes) WHERE episode = ?",
                        (int(bool(success)), note, scene, time.time(), episode))

    def undo(self, episode: int) -> None:
        """Unscore `episode`, which must be the last score entered (and drop an unstarted confirm
        plan that depended on it); ScoreConflict (naming the last scored episode) otherwise."""
        self._check_planned(episode)
        with self._transaction() as con:
            last = self._last_scored()
            if episode != last:
                raise ScoreConflict(f"episode {episode} is not the last one scored; that is {last}",
                                    last_scored=last)
            con.execute("UPDATE episodes SET success = NULL, note = NULL, scene = NULL, scored_at = NULL, "
                        "entry = NULL WHERE episode = ?", (episode,))
            if self._one("SELECT phase FROM episodes WHERE episode = ?", (episode,))[0] == "search":
                con.execute("DELETE FROM episodes WHERE phase = 'confirm'")

    def status(self) -> dict:
        """Scored and total episodes (planned grows by 3 x M when the confirm phase is planned),
        the due and the last scored episode, and the verdict once every episode is scored."""
        return self._refresh()

    def verdict(self) -> dict:
        """Confirm-phase success per arm with Wilson intervals, and each finalist's one-sided
        p-value against the base, Holm-adjusted over the two: a paired exact test when scene ids
        pair every finalist episode with a base episode, else Fisher's exact test (unpaired)."""
        status = self.status()
        if "verdict" in status:
            return status["verdict"]
        raise UserError(f"the session is not finished: {status['scored']} of {status['total']} "
                        "episodes scored")

    def scores(self) -> list[dict]:
        """Every planned episode with its score so far and its place in the order of entry (arm
        names included: for the record, not for the operator's screen)."""
        self._refresh()
        cols = ("episode", "phase", "arm", "success", "note", "scene", "scored_at", "entry")
        return [dict(zip(cols, r, strict=True)) for r in
                self._con.execute(f"SELECT {', '.join(cols)} FROM episodes ORDER BY episode")]

    def _refresh(self) -> dict:
        """Plan the confirm phase if due, bring the derived files in line with the store, and
        return the status."""
        self._check_store()
        self._plan_confirm_if_due()
        self._save_tickets()
        status = self._status()
        self._save_verdict(status.get("verdict"))
        return status

    def _status(self) -> dict:
        scored, planned = self._one("SELECT COUNT(success), COUNT(*) FROM episodes")
        search = self.plan.tickets * self.plan.episodes_per_ticket
        status = {"scored": scored, "total": self.plan.episodes, "planned": planned,
                  "phase": "confirm" if planned > search else "search", "due": self._due(),
                  "last_scored": self._last_scored()}
        if scored == self.plan.episodes:
            status["verdict"] = self._verdict()
        return status

    def _verdict(self) -> dict:
        rows = self._con.execute("SELECT arm, success, scene FROM episodes WHERE phase = 'confirm' "
                                 "AND success IS NOT NULL ORDER BY episode").fetchall()
        outcomes: dict[str, dict[str | None, bool]] = {}
        lists: dict[str, list[bool]] = {}
        for arm, success, scene in rows:
            outcomes.setdefault(arm, {})[scene] = bool(success)
            lists.setdefault(arm, []).append(bool(success))
        finalists = [a for a in lists if a != BASE]
        tests, p_raw = {}, []
        for arm in finalists:
            paired = _pairs(outcomes[arm], outcomes[BASE], len(lists[arm]), len(lists[BASE]))
            if paired:
                tests[arm] = "paired exact McNemar (sign) test on scene ids"
                p_raw.append(paired_exact_test(*paired))
            else:
                tests[arm] = "Fisher's exact test, unpaired"
                table = [[sum(lists[arm]), len(lists[arm]) - sum(lists[arm])],
                         [sum(lists[BASE]), len(lists[BASE]) - sum(lists[BASE])]]
                p_raw.append(float(fisher_exact(table, alternative="greater").pvalue))
        arms = {BASE: Rate.of(lists[BASE]).to_dict()}
        for arm, p in zip(finalists, holm_adjust(p_raw), strict=True):
            arms[arm] = {**Rate.of(lists[arm]).to_dict(), "p_value": p, "test": tests[arm],
                         "golden": p < 0.05, "verdict": "golden" if p < 0.05 else "not golden"}
        used = " and ".join(sorted(set(tests.values())))
        return {"arms": arms, "note": f"p-values: {used}; one-sided, finalist better than base, "
                                      "Holm-adjusted over the 2 finalists; 'golden' means p < 0.05"}

    def _plan_confirm_if_due(self) -> None:
        if not self._confirm_due():
            return
        with self._transaction() as con:
            if not self._confirm_due():  # another process planned it meanwhile
                return
            wins = self._search_successes()
            top = sorted(wins, key=lambda a: -wins[a])[:2]  # stable: ties keep candidate order
            arms = [arm for arm in (*top, BASE) for _ in range(self.plan.confirm)]
            np.random.default_rng([self.plan.seed, 1]).shuffle(arms)
            start = self.plan.tickets * self.plan.episodes_per_ticket
            con.executemany("INSERT INTO episodes (episode, phase, arm) VALUES (?, 'confirm', ?)",
                            [(start + i, a) for i, a in enumerate(arms)])

    def _confirm_due(self) -> bool:
        left, confirm = self._one("SELECT SUM(success IS NULL AND phase = 'search'), "
                                  "SUM(phase = 'confirm') FROM episodes")
        return not left and not confirm

    def _search_successes(self) -> dict[str, int]:
        """Search successes per candidate, in candidate order."""
        return dict(self._con.execute(
            "SELECT arms.arm, SUM(success) FROM arms JOIN episodes USING (arm) WHERE phase = 'search' "
            "GROUP BY arms.arm ORDER BY arms.rowid").fetchall())

    def _finalists(self) -> list[str]:
        return [a for (a,) in self._con.execute("SELECT DISTINCT arm FROM episodes WHERE phase = 'confirm' "
                                                "AND arm != ? ORDER BY arm", (BASE,))]

    def _save_tickets(self) -> None:
        """The finalists as ticket files in tickets/, ready to deploy once the verdict is in; a
        missing one is written again, one no longer a finalist (after an undo) removed."""
        folder, finalists = self.path.parent / "tickets", self._finalists()
        for old in folder.glob("*.safetensors"):
            if old.stem not in finalists and old.is_file():
                old.unlink()
        wins = self._search_successes() if finalists else {}
        for arm in finalists:
            if not (folder / f"{arm}.safetensors").is_file():
                meta = {"policy": self.plan.policy, "policy_fingerprint": self.plan.policy_fingerprint,
                        "session_search": {"successes": int(wins[arm]),
                                           "episodes": self.plan.episodes_per_ticket}}
                Ticket(self._noise(arm), meta).save(folder / f"{arm}.safetensors")

    def _save_verdict(self, verdict: dict | None) -> None:
        """summary.json and verdict.png beside the store once the session is complete (none before)."""
        summary, png = self.path.parent / "summary.json", self.path.parent / "verdict.png"
        if verdict is None:
            summary.unlink(missing_ok=True)
            png.unlink(missing_ok=True)
            return
        text = json.dumps({"session": self.name, "plan": asdict(self.plan),
                           "search_successes": self._search_successes(),
                           "tickets": {a: f"tickets/{a}.safetensors" for a in self._finalists()},
                           "verdict": verdict}, indent=2) + "\n"
        if png.is_file() and summary.is_file() and summary.read_text() == text:
            return
        from goldenticket.plots import arms_png

        arms_png(verdict["arms"], png, f"Session {self.name}: {self.plan.policy}",
                 what="confirm-phase success", unit="episodes per arm")
        write_atomic(summary, text)  # last: a summary.json that matches says verdict.png is written

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
        return self._one("SELECT MIN(episode) FROM episodes WHERE success IS NULL")[0]

    def _last_scored(self) -> int | None:
        row = self._one("SELECT episode FROM episodes WHERE entry IS NOT NULL ORDER BY entry DESC LIMIT 1")
        return None if row is None else row[0]

    def _noise(self, arm: str) -> np.ndarray:
        blob = self._one("SELECT noise FROM arms WHERE arm = ?", (arm,))[0]
        return np.frombuffer(blob, dtype=np.float32).reshape(self.plan.noise_shape).copy()

    def _one(self, sql: str, args: tuple = ()):
        return self._con.execute(sql, args).fetchone()


def _pairs(arm: dict, base: dict, n_arm: int, n_base: int) -> tuple[list[bool], list[bool]] | None:
    """Outcomes paired by scene id, if every episode of both arms has one, each scene once per arm
    and the same scenes in both arms; else None."""
    if None in arm or None in base or len(arm) != n_arm or len(base) != n_base or set(arm) != set(base):
        return None
    scenes = sorted(arm)
    return [arm[s] for s in scenes], [base[s] for s in scenes]


def _ticket_id(noise: np.ndarray, plan: Plan) -> str:
    return Ticket(noise, {"policy_fingerprint": plan.policy_fingerprint}).id


def _identity(path: Path) -> tuple[int, int]:
    info = os.stat(path)
    return info.st_dev, info.st_ino


def _connect(path: Path) -> sqlite3.Connection:
    try:
        con = sqlite3.connect(path, timeout=30, check_same_thread=False)
        con.execute("PRAGMA journal_mode = WAL")
        con.execute("PRAGMA synchronous = FULL")  # a score survives kill -9 and power loss
    except sqlite3.Error as e:
        raise UserError(f"{path}: cannot open the session ({e})") from None
    return con

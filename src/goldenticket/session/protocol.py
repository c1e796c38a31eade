"""A real-robot search session: the paper's protocol, scored by a person, kept in SQLite.

Search: N random candidate tickets x K episodes, in a shuffled order. Confirm: the two
candidates with the most search successes (ties: the earlier candidate) and the base policy,
M episodes each, interleaved in a shuffled order so the operator cannot tell which arm runs.
Every score is written the moment it is entered; the next episode is always the first
unscored one, so a restart resumes where it stopped.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import fisher_exact

from goldenticket.errors import UserError
from goldenticket.stats import Rate, holm_adjust, paired_exact_test
from goldenticket.tickets import Ticket

FILE = "session.sqlite"
BASE = "base"
_SCHEMA = """
CREATE TABLE plan (id INTEGER PRIMARY KEY CHECK (id = 0), value TEXT NOT NULL);
CREATE TABLE arms (arm TEXT PRIMARY KEY, noise BLOB);
CREATE TABLE episodes (
    episode INTEGER PRIMARY KEY, phase TEXT NOT NULL, arm TEXT NOT NULL,
    success INTEGER, note TEXT, scene TEXT, scored_at REAL
);
"""


class ScoreConflict(UserError):
    """The episode was scored already, or is not (yet) in the plan."""


@dataclass(frozen=True)
class Plan:
    policy: str
    policy_fingerprint: str
    noise_shape: tuple[int, int]
    tickets: int
    episodes_per_ticket: int
    confirm: int
    seed: int


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
        self._con = _connect(self.path)
        try:
            fields = json.loads(self._one("SELECT value FROM plan")[0])
        except (sqlite3.DatabaseError, TypeError):
            raise UserError(f"{self.path}: not a goldenticket session, or damaged") from None
        self.plan = Plan(**{**fields, "noise_shape": tuple(fields["noise_shape"])})

    @classmethod
    def new(cls, folder: str | Path, plan: Plan) -> Session:
        """Plan the search phase and write it; refuses a folder that holds a session already."""
        for name, value in (("tickets", plan.tickets), ("episodes-per-ticket", plan.episodes_per_ticket),
                            ("confirm", plan.confirm)):
            if value < 1:
                raise UserError(f"--{name} must be at least 1, got {value}")
        if plan.tickets < 2:
            raise UserError(f"--tickets must be at least 2 (the confirm phase takes the top 2), "
                            f"got {plan.tickets}")
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
        """The first unscored episode (planning the confirm phase once search is scored), or None."""
        self._plan_confirm_if_due()
        row = self._one("SELECT episode FROM episodes WHERE success IS NULL ORDER BY episode LIMIT 1")
        return None if row is None else self.episode(row[0])

    def episode(self, episode: int) -> NextEpisode:
        """What the robot runs for one planned episode."""
        arm = self._one("SELECT arm FROM episodes WHERE episode = ?", (episode,))[0]
        if arm == BASE:
            return NextEpisode(episode, BASE, None, [self.plan.seed, episode])
        return NextEpisode(episode, arm, self._noise(arm), None)

    def score(self, episode: int, success: bool, note: str = "", scene: str | None = None) -> None:
        """Record one episode's outcome; ScoreConflict if it is scored already or not planned."""
        with self._con:
            cur = self._con.execute(
                "UPDATE episodes SET success = ?, note = ?, scene = ?, scored_at = ? "
                "WHERE episode = ? AND success IS NULL",
                (int(bool(success)), note, scene, time.time(), episode))
        if cur.rowcount == 0:
            known = self._one("SELECT success FROM episodes WHERE episode = ?", (episode,))
            why = "not in the plan" if known is None else "scored already"
            raise ScoreConflict(f"episode {episode} is {why}")

    def undo(self) -> int | None:
        """Unscore the most recently scored episode (and drop an unstarted confirm plan that
        depended on it); returns its number, or None when nothing is scored."""
        with self._con:
            row = self._con.execute("SELECT episode, phase FROM episodes WHERE success IS NOT NULL "
                                    "ORDER BY scored_at DESC, episode DESC LIMIT 1").fetchone()
            if row is None:
                return None
            self._con.execute("UPDATE episodes SET success = NULL, note = NULL, scene = NULL, "
                              "scored_at = NULL WHERE episode = ?", (row[0],))
            if row[1] == "search":
                self._con.execute("DELETE FROM episodes WHERE phase = 'confirm'")
        if row[1] == "search":  # the finalists may change: their files are written again
            shutil.rmtree(self.path.parent / "tickets", ignore_errors=True)
        return row[0]

    def status(self) -> dict:
        """Scored and total episodes (the total grows by 3 x M when the confirm phase is planned),
        and the verdict once every episode is scored."""
        self._plan_confirm_if_due()
        scored, planned = self._one("SELECT COUNT(success), COUNT(*) FROM episodes")
        plan = self.plan
        total = plan.tickets * plan.episodes_per_ticket + 3 * plan.confirm
        status = {"scored": scored, "total": total, "planned": planned,
                  "phase": "confirm" if planned > plan.tickets * plan.episodes_per_ticket else "search"}
        if scored == total:
            status["verdict"] = self._verdict()
        return status

    def verdict(self) -> dict:
        """Confirm-phase success per arm with Wilson intervals, and each finalist's one-sided
        p-value against the base, Holm-adjusted over the two: a paired exact test when scene ids
        pair every finalist episode with a base episode, else Fisher's exact test (unpaired)."""
        status = self.status()
        if "verdict" in status:
            return status["verdict"]
        raise UserError(f"the session is not finished: {status['scored']} of {status['total']} "
                        "episodes scored")

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

    def scores(self) -> list[dict]:
        """Every planned episode with its score so far (arm names included: for the record, not
        for the operator's screen)."""
        self._plan_confirm_if_due()
        cols = ("episode", "phase", "arm", "success", "note", "scene", "scored_at")
        return [dict(zip(cols, r, strict=True)) for r in
                self._con.execute(f"SELECT {', '.join(cols)} FROM episodes ORDER BY episode")]

    def _plan_confirm_if_due(self) -> None:
        plan = self.plan
        with self._con:
            left, confirm = self._con.execute("SELECT SUM(success IS NULL AND phase = 'search'), "
                                              "SUM(phase = 'confirm') FROM episodes").fetchone()
            if left or confirm:
                return
            wins = dict(self._con.execute("SELECT arm, SUM(success) FROM episodes WHERE phase = 'search' "
                                          "GROUP BY arm").fetchall())
            candidates = [a for (a,) in self._con.execute("SELECT arm FROM arms ORDER BY rowid") if a in wins]
            top = sorted(candidates, key=lambda a: -wins[a])[:2]  # stable: ties keep candidate order
            arms = [arm for arm in (*top, BASE) for _ in range(plan.confirm)]
            np.random.default_rng([plan.seed, 1]).shuffle(arms)
            start = plan.tickets * plan.episodes_per_ticket  # the same rows from any process that plans
            self._con.executemany("INSERT OR IGNORE INTO episodes (episode, phase, arm) "
                                  "VALUES (?, 'confirm', ?)", [(start + i, a) for i, a in enumerate(arms)])
        for arm in top:  # the finalists as ticket files, ready to deploy once the verdict is in
            meta = {"policy": plan.policy, "policy_fingerprint": plan.policy_fingerprint,
                    "session_search": {"successes": int(wins[arm]), "episodes": plan.episodes_per_ticket}}
            Ticket(self._noise(arm), meta).save(self.path.parent / "tickets" / f"{arm}.safetensors")

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


def _connect(path: Path) -> sqlite3.Connection:
    try:
        con = sqlite3.connect(path, timeout=30, check_same_thread=False)
        con.execute("PRAGMA journal_mode = WAL")
        con.execute("PRAGMA synchronous = FULL")  # a score survives kill -9 and power loss
    except sqlite3.Error as e:
        raise UserError(f"{path}: cannot open the session ({e})") from None
    return con

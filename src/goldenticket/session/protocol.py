"""A real-robot search session scored by a person, kept in SQLite.

Two protocols over N random candidate tickets, each episode's arm hidden from the operator:
- fixed (the paper's): N x K search episodes in a shuffled order; then the two candidates with
  the most search successes (ties: the earlier candidate) and the base policy, M episodes each,
  interleaved in a shuffled order; the verdict once every episode is scored.
- sequential: a race (successive elimination) in rounds, each in a shuffled order: every
  candidate FIRST_ROUND episodes, then ROUND more per candidate still in, a candidate dropped
  once it trails the leader by DROP_Z standard errors, until one is left or N x K episodes are
  spent; then the finalist and the base run in pairs (one episode each, in an order drawn from
  the seed), at most M pairs, and the session stops at the first pair after which the
  sequential sign test decides (golden, futile, or out of reach).
Every score is written the moment it is entered; only the due episode (the first unscored one)
can be scored, and what is planned next is a function of the seed and the scores, so a restart
resumes where it stopped. The files beside the store (the finalists' tickets, and once complete
summary.json and verdict.png) are derived from it and brought in line with it whenever the
session is opened or asked what is due.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.stats import fisher_exact

from goldenticket.errors import OptionError, UserError
from goldenticket.files import write_atomic
from goldenticket.stats import Rate, Sequential, holm_adjust, paired_exact_test, sequential_sign_test
from goldenticket.tickets import Ticket

FILE = "session.sqlite"
BASE = "base"
MAX_EPISODES = 100_000
MAX_CAP = 1000  # pairs under sequential stopping: its test is calibrated exactly over the cap
STOPPING = ("sequential", "fixed")
DEFAULT_CONFIRM = {"fixed": 50, "sequential": 70}  # sequential: never more episodes than fixed
FIRST_ROUND, ROUND, DROP_Z = 10, 2, 1.5  # the race (benchmarks/session_sequential.py chose them)
FUTILITY = (0.7, 0.2)  # (q1, beta) of the confirm test's futility stop (stats.sequential_sign_test)
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
    stopping: str = "sequential"
    alpha: float = 0.05

    def __post_init__(self) -> None:
        if self.stopping not in STOPPING:
            raise OptionError(f"stopping must be one of {', '.join(STOPPING)}, got {self.stopping!r}",
                              "stopping")
        if not 0 < self.alpha < 1:
            raise OptionError(f"alpha must be between 0 and 1, got {self.alpha}", "alpha")
        for name, value, least in (("tickets", self.tickets, 2), ("confirm", self.confirm, 1),
                                   ("episodes_per_ticket", self.episodes_per_ticket, 1)):
            if value < least:
                why = " (the confirm phase takes the top 2)" if name == "tickets" else ""
                raise OptionError(f"{name} must be at least {least}{why}, got {value}", name)
        if self.episodes > MAX_EPISODES:
            raise OptionError(f"a session plans at most {MAX_EPISODES} episodes (tickets x "
                              f"episodes_per_ticket + {self.arms} x confirm), got {self.episodes}",
                              "tickets", "episodes_per_ticket", "confirm")
        least = math.floor(math.log2(1 / self.alpha)) + 1  # fewer pairs cannot reach the level alpha
        if self.stopping == "sequential" and not least <= self.confirm <= MAX_CAP:
            raise OptionError(f"under sequential stopping confirm (the cap of pairs) must be between {least} "
                              f"(for alpha {self.alpha}) and {MAX_CAP}, got {self.confirm}",
                              "confirm", "alpha")

    @property
    def first_round(self) -> int:
        """Search episodes per candidate in the first round: K for fixed (the only round)."""
        each = self.episodes_per_ticket
        return each if self.stopping == "fixed" else min(FIRST_ROUND, each)

    @property
    def arms(self) -> int:
        """Arms in the confirm phase: the finalists (2 fixed, 1 sequential) and the base."""
        return 3 if self.stopping == "fixed" else 2

    @property
    def episodes(self) -> int:
        """Every episode the session may run: at most N x K search episodes, then M per confirm arm."""
        return self.tickets * self.episodes_per_ticket + self.arms * self.confirm


@dataclass(frozen=True)
class Race:
    """The search replayed round by round from its planned episodes: the end of each round
    planned, the candidates still in after the last fully scored one (most search successes
    first; ties: the earlier candidate), and the episodes each runs in the next round (0: the
    search is over, the first `plan.arms - 1` of `alive` are the finalists)."""

    ends: list[int]
    alive: list[str]
    next_round: int


def race(plan: Plan, candidates: list[str], search: list[tuple[str, bool | None]]) -> Race:
    """Replay the search episodes `search` ((arm, success or None) in episode order) of a plan
    whose candidates are `candidates`, in their order. Fixed: one round; the top 2 go on.
    Sequential: successive elimination (Even-Dar, Mannor and Mansour, JMLR 7, 2006): after each
    round, every candidate that trails() the leader is dropped; the next round comes while more
    than one is left and it fits in N x K episodes. `next_round` is 0 too while a round is
    being scored."""
    rank, wins = {arm: i for i, arm in enumerate(candidates)}, dict.fromkeys(candidates, 0)
    alive, start, each, runs, ends = list(candidates), 0, plan.first_round, 0, []
    while start < len(search):
        ends.append(start + len(alive) * each)
        if any(success is None for _, success in search[start:ends[-1]]):
            return Race(ends, alive, 0)
        for arm, success in search[start:ends[-1]]:
            wins[arm] += bool(success)
        alive = sorted(alive, key=lambda a: (-wins[a], rank[a]))
        if plan.stopping == "fixed":
            return Race(ends, alive[:2], 0)
        runs += each
        alive = [a for a in alive if not trails(wins[alive[0]], wins[a], runs)]
        start, each = ends[-1], ROUND
    fits = start + len(alive) * ROUND <= plan.tickets * plan.episodes_per_ticket
    return Race(ends, alive, ROUND if len(alive) > 1 and fits else 0)


def trails(lead, wins, runs):
    """Whether a candidate with `wins` search successes trails the leader's `lead`, both in `runs`
    episodes, by DROP_Z standard errors of the difference (the pooled two-proportion z statistic,
    with one success and one failure added); counts may be numpy arrays."""
    p = (lead + wins + 1) / (2 * runs + 2)
    return lead - wins >= DROP_Z * np.sqrt(2 * runs * p * (1 - p))


@dataclass(frozen=True)
class NextEpisode:
    """What the robot runs next: a ticket's noise for every policy call, or, for the base arm
    (`noise` None), fresh N(0, I) noise of `noise_shape` per call from
    `numpy.random.default_rng(gaussian_seed)`; `noise_source()` gives either as a function."""

    episode: int
    ticket_id: str
    noise: np.ndarray | None
    gaussian_seed: list[int] | None
    noise_shape: tuple[int, int] | None = None

    def to_json(self) -> dict:
        noise = None if self.noise is None else self.noise.tolist()
        return {"episode": self.episode, "ticket_id": self.ticket_id, "noise": noise,
                "gaussian_seed": self.gaussian_seed, "noise_shape": self.noise_shape}

    @classmethod
    def from_json(cls, data: dict) -> NextEpisode:
        noise = None if data["noise"] is None else np.asarray(data["noise"], dtype=np.float32)
        shape = data.get("noise_shape")
        return cls(data["episode"], data["ticket_id"], noise, data["gaussian_seed"],
                   None if shape is None else tuple(shape))

    def noise_source(self):
        """A function returning the noise for the next policy call: the ticket every time, or the
        base arm's next N(0, I) draw."""
        if self.noise is not None:
            return lambda: self.noise
        rng = np.random.default_rng(self.gaussian_seed)
        return lambda: rng.standard_normal(self.noise_shape, dtype=np.float32)


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
        rng = np.random.default_rng([plan.seed, 0])
        candidates = rng.standard_normal((plan.tickets, *plan.noise_shape), dtype=np.float32)
        arms = {_ticket_id(noise, plan): noise for noise in candidates}
        order = [arm for arm in arms for _ in range(plan.first_round)]
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
        the arm), and the verdict once the session is complete."""
        return self._refresh()

    def verdict(self) -> dict:
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
        self._save_tickets()
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

    def _verdict(self) -> dict:
        if self.plan.stopping == "sequential":
            return self._sequential_verdict()
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
        alpha = self.plan.alpha
        arms = {BASE: Rate.of(lists[BASE]).to_dict()}
        for arm, p in zip(finalists, holm_adjust(p_raw), strict=True):
            arms[arm] = {**Rate.of(lists[arm]).to_dict(), "p_vs_base": p, "test": tests[arm],
                         "golden": p < alpha, "verdict": "golden" if p < alpha else "not golden"}
        used = " and ".join(sorted(set(tests.values())))
        stopping = {"rule": "fixed", "alpha": alpha, "episodes": self.plan.episodes,
                    "reason": "every planned episode scored",
                    "why": f"the fixed protocol: all {self.plan.episodes} planned episodes scored"}
        return {"arms": arms, "stopping": stopping,
                "note": f"p-values: {used}; one-sided, finalist better than base, Holm-adjusted over the "
                        f"2 finalists; 'golden' means p < {alpha:g}"}

    def _sequential_verdict(self) -> dict:
        finalist, ticket, base, by_scene = self._confirm_pairs()
        test = self._test()
        name = "sequential sign test, " + ("pairs matched by scene id" if by_scene else "unpaired episodes")
        arms = {BASE: Rate.of(base).to_dict(),
                finalist: {**Rate.of(ticket).to_dict(), "p_vs_base": test.p_value, "test": name,
                           "golden": test.decision == "golden", "verdict": test.decision}}
        reason = "cap reached" if test.pairs == self.plan.confirm else "decided early"
        e, threshold = f"{test.e_value:.3g}", f"{test.threshold:.3g}"
        (q1, beta), discordant = FUTILITY, test.ticket_only + test.base_only
        detail = {"threshold reached": f"the e-value reached {e} (threshold {threshold})",
                  "futile": f"the base won {test.base_only} of {discordant} discordant pairs: no difference "
                            f"is {1 / beta:g} or more times likelier than a ticket winning {q1:.0%} of them",
                  "out of reach": f"the e-value (at most {e} so far) cannot reach {threshold} within the cap",
                  "cap reached": f"the e-value stayed below {threshold} (at most {e})"}
        scored, stopped_at = self._one("SELECT COUNT(success), MAX(scored_at) FROM episodes")
        stopping = {"rule": "sequential", "test": name, "alpha": self.plan.alpha, "cap": self.plan.confirm,
                    "threshold": test.threshold, "e_value": test.e_value,
                    "futility": {"q1": q1, "beta": beta}, "pairs": test.pairs,
                    "ticket_only": test.ticket_only, "base_only": test.base_only, "episodes": scored,
                    "stopped_at": stopped_at, "reason": reason,
                    "why": f"{reason} after {test.pairs} of at most {self.plan.confirm} pairs ({scored} "
                           f"episodes in all): {detail[test.reason]}; {test.decision}"}
        return {"arms": arms, "stopping": stopping,
                "note": f"p-value: the sequential sign test, one-sided, ticket better than base, tested "
                        f"after every pair of the confirm phase; 'golden' means its mixture e-value reached "
                        f"{threshold}, which under no difference happens within {self.plan.confirm} pairs "
                        f"with chance below {self.plan.alpha:g} (p < {self.plan.alpha:g}); not golden early "
                        f"once out of reach, or futile (which stops a ticket that wins {q1:.0%} of the "
                        f"discordant pairs with chance at most {beta:g})"}

    def _test(self) -> Sequential | None:
        """The sequential sign test on the confirm pairs scored so far; None for a fixed session."""
        if self.plan.stopping == "fixed":
            return None
        _, ticket, base, _ = self._confirm_pairs()
        return sequential_sign_test(ticket, base, self.plan.confirm, self.plan.alpha, FUTILITY)

    def _confirm_pairs(self) -> tuple[str | None, list[bool], list[bool], bool]:
        """The finalist, its and the base's outcomes over the scored confirm pairs, and whether
        each pair's two episodes name the same scene."""
        rows = self._con.execute("SELECT arm, success, scene FROM episodes WHERE phase = 'confirm' "
                                 "AND success IS NOT NULL ORDER BY episode").fetchall()
        pairs = [sorted(rows[i:i + 2], key=lambda r: r[0] == BASE) for i in range(0, len(rows) - 1, 2)]
        finalist = next(iter(self._finalists()), None)
        by_scene = all(a[2] is not None and a[2] == b[2] for a, b in pairs)
        return finalist, [bool(a[1]) for a, _ in pairs], [bool(b[1]) for _, b in pairs], by_scene

    def _plan_next_if_due(self) -> None:
        if not self._round_due():
            return
        with self._transaction() as con:
            if not self._round_due():  # another process planned it meanwhile
                return
            planned, race_ = len(self._search()), self._race()
            if race_.next_round:  # a search round: its candidates' episodes in a shuffled order
                arms = [arm for arm in race_.alive for _ in range(race_.next_round)]
                np.random.default_rng([self.plan.seed, 2, len(race_.ends)]).shuffle(arms)
            elif self.plan.stopping == "fixed":  # the confirm phase: every arm's episodes shuffled
                arms = [arm for arm in (*race_.alive, BASE) for _ in range(self.plan.confirm)]
                np.random.default_rng([self.plan.seed, 1]).shuffle(arms)
            else:  # pairs of the finalist and the base, each pair's order drawn from the seed
                pairs = np.array([[race_.alive[0], BASE]] * self.plan.confirm)
                arms = np.random.default_rng([self.plan.seed, 1]).permuted(pairs, axis=1).ravel().tolist()
            phase = "search" if race_.next_round else "confirm"
            con.executemany("INSERT INTO episodes (episode, phase, arm) VALUES (?, ?, ?)",
                            [(planned + i, phase, a) for i, a in enumerate(arms)])

    def _round_due(self) -> bool:
        """Whether every planned episode is scored and the confirm phase not planned yet."""
        scored, planned, confirm = self._one("SELECT COUNT(success), COUNT(*), SUM(phase = 'confirm') "
                                             "FROM episodes")
        return scored == planned and not confirm

    def _race(self) -> Race:
        candidates = [a for (a,) in self._con.execute("SELECT arm FROM arms WHERE arm != ? ORDER BY rowid",
                                                      (BASE,))]
        return race(self.plan, candidates, self._search())

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

    def _save_tickets(self) -> None:
        """The finalists as ticket files in tickets/, ready to deploy once the verdict is in; a
        missing one is written again, one no longer a finalist (after an undo) removed."""
        folder, finalists = self.path.parent / "tickets", self._finalists()
        for old in folder.glob("*.safetensors"):
            if old.stem not in finalists and old.is_file():
                old.unlink()
        record = self._search_record() if finalists else {}
        for arm in finalists:
            if not (folder / f"{arm}.safetensors").is_file():
                meta = {"policy": self.plan.policy, "policy_fingerprint": self.plan.policy_fingerprint,
                        "session_search": {"successes": record[arm][0], "episodes": record[arm][1]}}
                Ticket(self._noise(arm), meta).save(folder / f"{arm}.safetensors")

    def _save_verdict(self, verdict: dict | None) -> None:
        """summary.json and verdict.png beside the store once the session is complete (none before)."""
        summary, png = self.path.parent / "summary.json", self.path.parent / "verdict.png"
        if verdict is None:
            summary.unlink(missing_ok=True)
            png.unlink(missing_ok=True)
            return
        record, plan = self._search_record(), self.plan
        race_ = {} if plan.stopping == "fixed" else {
            "race": {"first_round": plan.first_round, "round": ROUND, "drop_z": DROP_Z}}
        text = json.dumps({"session": self.name, "plan": asdict(plan), **race_,
                           "search_successes": {arm: won for arm, (won, _) in record.items()},
                           "search_episodes": {arm: n for arm, (_, n) in record.items()},
                           "tickets": {a: f"tickets/{a}.safetensors" for a in self._finalists()},
                           "verdict": verdict}, indent=2) + "\n"
        if png.is_file() and summary.is_file() and summary.read_text() == text:
            return
        from goldenticket.plots import arms_png

        stopped = "" if self.plan.stopping == "fixed" else f" ({verdict['stopping']['reason']})"
        arms_png(verdict["arms"], png, f"Session {self.name}: {self.plan.policy}{stopped}",
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

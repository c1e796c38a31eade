"""A session's plan and its race, pure functions of the seed and the scores (no I/O).

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
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import partial

import numpy as np

from goldenticket.config import DEFAULT_CONFIRM
from goldenticket.errors import OptionError, flags_in
from goldenticket.ticket_search import racing
from goldenticket.tickets import ticket_id

BASE = "base"
MAX_EPISODES = 100_000
MAX_CAP = 1000  # pairs under sequential stopping: its test is calibrated exactly over the cap
FIRST_ROUND, ROUND, DROP_Z = 10, 2, 1.5  # the race (benchmarks/session_sequential.py chose them)
FUTILITY = (0.7, 0.2)  # (q1, beta) of the confirm test's futility stop (stats.sequential_sign_test)


class PlanError(OptionError):
    """A bad plan field; on the command line each field is the flag `session new` generates for
    it (`tickets` is `--tickets`, not the `--ticket` of evaluate)."""

    def as_flags(self, spelled: dict[str, str] | None = None) -> str:
        return flags_in(str(self), self.names)


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
        if self.stopping not in DEFAULT_CONFIRM:  # the stopping rules, each with its confirm default
            raise PlanError(f"stopping must be one of {', '.join(DEFAULT_CONFIRM)}, got {self.stopping!r}",
                            "stopping")
        if not 0 < self.alpha < 1:
            raise PlanError(f"alpha must be between 0 and 1, got {self.alpha}", "alpha")
        for name, value, least in (("tickets", self.tickets, 2), ("confirm", self.confirm, 1),
                                   ("episodes_per_ticket", self.episodes_per_ticket, 1)):
            if value < least:
                why = " (the confirm phase takes the top 2)" if name == "tickets" else ""
                raise PlanError(f"{name} must be at least {least}{why}, got {value}", name)
        if self.episodes > MAX_EPISODES:
            raise PlanError(f"a session plans at most {MAX_EPISODES} episodes (tickets x "
                            f"episodes_per_ticket + {self.arms} x confirm), got {self.episodes}",
                            "tickets", "episodes_per_ticket", "confirm")
        least = math.floor(math.log2(1 / self.alpha)) + 1  # fewer pairs cannot reach the level alpha
        if self.stopping == "sequential" and not least <= self.confirm <= MAX_CAP:
            raise PlanError(f"under sequential stopping confirm (the cap of pairs) must be between {least} "
                            f"(for alpha {self.alpha}) and {MAX_CAP}, got {self.confirm}", "confirm", "alpha")

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
    whose candidates are `candidates`, in their order, through a `racing.Race` scored by search
    successes. Fixed: one round; the top 2 go on. Sequential: successive elimination (Even-Dar,
    Mannor and Mansour, JMLR 7, 2006): after each round, every candidate that trails() the leader
    is dropped (`_leaders`); the next round comes while more than one is left and it fits in N x K
    episodes. `next_round` is 0 too while a round is being scored."""
    rounds = 1 if plan.stopping == "fixed" else None
    contest = racing.Race(len(candidates), partial(_leaders, plan), _wins, rounds)
    start, ends = 0, []
    while start < len(search) and not contest.over:
        ends.append(start + len(contest.alive) * (ROUND if contest.round else plan.first_round))
        played = search[start:ends[-1]]
        if any(success is None for _, success in played):
            break
        contest.record([[bool(success) for arm, success in played if arm == candidates[i]]
                        for i in contest.alive])
        start = ends[-1]
    alive = [candidates[i] for i in contest.ranked()]
    if contest.over:
        return Race(ends, alive[:2], 0)
    if start < len(search):  # a round being scored
        return Race(ends, alive, 0)
    fits = start + len(alive) * ROUND <= plan.tickets * plan.episodes_per_ticket
    return Race(ends, alive, ROUND if len(alive) > 1 and fits else 0)


def _wins(rounds: list[list[bool]]) -> int:
    """A candidate's search successes, over its rounds."""
    return sum(map(sum, rounds))


def _leaders(plan: Plan, contest: racing.Race) -> list[int]:
    """Successive elimination's cut: the candidates still in that do not trail() the leader, after
    the rounds `contest` has run (`plan.first_round` episodes each, then ROUND per round)."""
    ranked = contest.ranked()
    lead, runs = contest.score(ranked[0]), plan.first_round + ROUND * (contest.round - 1)
    return [i for i in ranked if not trails(lead, contest.score(i), runs)]


def trails(lead, wins, runs):
    """Whether a candidate with `wins` search successes trails the leader's `lead`, both in `runs`
    episodes, by DROP_Z standard errors of the difference (the pooled two-proportion z statistic,
    with one success and one failure added); counts may be numpy arrays."""
    p = (lead + wins + 1) / (2 * runs + 2)
    return lead - wins >= DROP_Z * np.sqrt(2 * runs * p * (1 - p))


def candidates(plan: Plan) -> tuple[dict[str, np.ndarray], list[str]]:
    """The candidate tickets' noise by ticket id, in their order, and the arms of the first
    round's episodes in their shuffled order, all drawn from the seed."""
    rng = np.random.default_rng([plan.seed, 0])
    noise = rng.standard_normal((plan.tickets, *plan.noise_shape), dtype=np.float32)
    arms = {ticket_id(n, plan.policy_fingerprint): n for n in noise}
    order = [arm for arm in arms for _ in range(plan.first_round)]
    rng.shuffle(order)
    return arms, order


def is_candidate(name: object) -> bool:
    """Whether `name` is named as `candidates` names a candidate: its ticket id, 12 lowercase hex
    digits."""
    return isinstance(name, str) and re.fullmatch("[0-9a-f]{12}", name) is not None


def next_episodes(plan: Plan, replayed: Race) -> tuple[str, list[str]]:
    """The phase and arms, in order, of the episodes planned once every planned one is scored:
    the next search round's (its candidates' episodes shuffled), else the confirm phase: fixed,
    every finalist's and the base's episodes shuffled; sequential, pairs of the finalist and the
    base, each pair's order drawn from the seed."""
    if replayed.next_round:
        arms = [arm for arm in replayed.alive for _ in range(replayed.next_round)]
        np.random.default_rng([plan.seed, 2, len(replayed.ends)]).shuffle(arms)
        return "search", arms
    if plan.stopping == "fixed":
        arms = [arm for arm in (*replayed.alive, BASE) for _ in range(plan.confirm)]
        np.random.default_rng([plan.seed, 1]).shuffle(arms)
        return "confirm", arms
    pairs = np.array([[replayed.alive[0], BASE]] * plan.confirm)
    return "confirm", np.random.default_rng([plan.seed, 1]).permuted(pairs, axis=1).ravel().tolist()

"""Success rates with confidence intervals, and the paired test a ticket must pass vs. the base."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import gammaln
from scipy.stats import binomtest


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval (no continuity correction) for a binomial success rate."""
    if n <= 0:
        raise ValueError(f"wilson_interval needs n >= 1, got n={n}")
    if not 0 <= successes <= n:
        raise ValueError(f"wilson_interval needs 0 <= successes <= n, got {successes}/{n}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    ci = binomtest(successes, n).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


def paired_exact_test(ticket: Sequence[bool], base: Sequence[bool]) -> float:
    """One-sided exact McNemar (sign) test that the ticket succeeds more often than the base.

    Both policies are rolled out on the same held-out seeds, so outcomes are paired. The test
    conditions on the seed: pairs where both succeed or both fail say nothing about which policy
    is better (they reflect how hard the seed is), so only discordant pairs carry information.
    Under the null of no difference each discordant pair is equally likely to favour either
    side, so with b ticket-only wins and c base-only wins, p = P(Binomial(b + c, 1/2) >= b).
    Returns 1.0 when there are no discordant pairs.
    """
    if len(ticket) != len(base):
        raise ValueError(
            f"paired outcomes differ in length: ticket {len(ticket)}, base {len(base)}"
        )
    b = sum(1 for t, s in zip(ticket, base, strict=True) if t and not s)
    c = sum(1 for t, s in zip(ticket, base, strict=True) if s and not t)
    if b + c == 0:
        return 1.0
    return float(binomtest(b, b + c, 0.5, alternative="greater").pvalue)


@dataclass(frozen=True)
class Rate:
    """A success rate over n episodes with its 95% Wilson interval."""

    successes: int
    n: int
    success_rate: float
    ci_low: float
    ci_high: float

    @classmethod
    def of(cls, successes: Sequence[bool]) -> Rate:
        """Summarise per-episode binary outcomes."""
        return cls.counted(sum(bool(s) for s in successes), len(successes))

    @classmethod
    def counted(cls, k: int, n: int) -> Rate:
        """`k` successes in `n` episodes."""
        low, high = wilson_interval(k, n)
        return cls(successes=k, n=n, success_rate=k / n, ci_low=low, ci_high=high)

    def to_dict(self) -> dict[str, float | int]:
        """JSON-able summary: success_rate, ci_low, ci_high, n."""
        return {
            "success_rate": self.success_rate,
            "ci_low": self.ci_low,
            "ci_high": self.ci_high,
            "n": self.n,
        }


def holm_adjust(p_values: Sequence[float]) -> list[float]:
    """Holm step-down adjusted p-values: controls the family-wise error over several tickets."""
    order = sorted(range(len(p_values)), key=lambda i: p_values[i])
    adjusted, running = [0.0] * len(p_values), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p_values) - rank) * p_values[i]))
        adjusted[i] = running
    return adjusted


def sign_test(wins: int, losses: int) -> float:
    """One-sided sign test across pairs: P(Binomial(wins + losses, 1/2) >= wins); ties dropped."""
    if wins < 0 or losses < 0:
        raise ValueError(f"sign_test needs counts >= 0, got {wins}, {losses}")
    if wins + losses == 0:
        return 1.0
    return float(binomtest(wins, wins + losses, 0.5, alternative="greater").pvalue)


def mixture_log_e(wins: int, losses: int) -> float:
    """Log of the mixture e-value of `wins` ticket-only and `losses` base-only pairs: the
    likelihood ratio of Bernoulli(q) against Bernoulli(1/2), averaged over q uniform on
    [1/2, 1] (Robbins 1970). It is a nonnegative supermartingale whenever q <= 1/2."""
    return float(_log_e_row(wins + losses)[wins])


def _log_e_row(n: int) -> np.ndarray:
    """mixture_log_e(w, n - w) for w = 0..n, in closed form: 2^(n+1) B(w+1, n-w+1) P(Beta > 1/2)
    = sum_{j<=w} C(n+1, j) / ((n+1) C(n, w))."""
    w = np.arange(n + 1)
    log_choose = gammaln(n + 2) - gammaln(w + 1) - gammaln(n + 2 - w)  # log C(n+1, w)
    return np.logaddexp.accumulate(log_choose) - np.log(n + 1) - (log_choose + np.log((n + 1 - w) / (n + 1)))


@lru_cache(maxsize=8)
def _log_e_table(cap: int) -> tuple[np.ndarray, ...]:
    """mixture_log_e(w, k - w) for w = 0..k, for every k = 0..cap."""
    return tuple(_log_e_row(k) for k in range(cap + 1))


def sequential_level(log_e: float, cap: int) -> float:
    """P(the mixture log e-value reaches `log_e` within `cap` discordant pairs), each pair a fair
    coin: exact, by dynamic programming over (pairs, ticket-only wins)."""
    table, alive, crossed = _log_e_table(cap), np.ones(1), 0.0
    if log_e <= table[0][0]:  # reached before the first pair: the e-value starts at 1
        return 1.0
    for k in range(1, cap + 1):
        step = np.zeros(k + 1)
        step[1:] += alive / 2
        step[:-1] += alive / 2
        hit = table[k] >= log_e
        crossed += step[hit].sum()
        step[hit] = 0.0
        alive = step
    return float(crossed)


@lru_cache(maxsize=64)
def sequential_threshold(cap: int, alpha: float) -> float:
    """The smallest log e-value whose level within `cap` pairs (sequential_level) is below
    alpha; inf when even `cap` wins in a row are not that rare."""
    values = np.unique(np.concatenate(_log_e_table(cap)))
    low, high = 0, len(values)
    while low < high:  # the level falls as the threshold rises
        middle = (low + high) // 2
        if sequential_level(values[middle], cap) < alpha:
            high = middle
        else:
            low = middle + 1
    return float(values[low]) if low < len(values) else math.inf


def futile(wins, losses, q1: float, beta: float):
    """Whether `wins` ticket-only and `losses` base-only pairs make the likelihood ratio of q = 1/2
    against q = q1 reach 1/beta (Wald's lower boundary); counts may be numpy arrays."""
    if not (0.5 < q1 < 1 and 0 < beta < 1):
        raise ValueError(f"futility needs 1/2 < q1 < 1 and 0 < beta < 1, got {q1}, {beta}")
    return wins * np.log(2 * q1) + losses * np.log(2 - 2 * q1) <= np.log(beta)


@dataclass(frozen=True)
class Sequential:
    """A sequential sign test after `pairs` pairs: the discordant counts, the largest e-value so
    far, its threshold and exact p-value, and the decision ("golden", "not golden", or None to
    go on) with its reason ("threshold reached", "futile", "out of reach", "cap reached")."""

    pairs: int
    ticket_only: int
    base_only: int
    e_value: float
    threshold: float
    p_value: float
    decision: str | None
    reason: str | None


def sequential_sign_test(ticket: Sequence[bool], base: Sequence[bool], cap: int, alpha: float = 0.05,
                         futility: tuple[float, float] | None = None) -> Sequential:
    """One-sided sequential test that the ticket succeeds more often than the base, decided
    after each pair (one episode per arm) until the first decision, with at most `cap` pairs.

    Only discordant pairs count (Wald 1947, double dichotomies; McNemar): under no difference a
    discordant pair favours the ticket with probability 1/2 when a pair shares its scene, and at
    most 1/2 for independent episodes. The statistic is the mixture e-value (mixture_log_e);
    golden once it reaches the threshold whose chance of being reached within `cap` pairs under
    no difference is below alpha (sequential_threshold, exact), so the type-I error is at most
    alpha whenever the test stops; not golden once the threshold is out of reach within the cap.
    futility (q1, beta): also not golden ("futile") once the likelihood ratio of q = 1/2 against
    q = q1 reaches 1/beta (Wald's sequential probability ratio test, 1945): a ticket that wins a
    discordant pair with probability q1 or more is stopped so with chance at most beta (Ville's
    inequality). It only ever stops for "not golden", so it leaves the type-I error as it is.
    p_value: the exact chance under no difference of an e-value as large as the largest seen.
    """
    if len(ticket) != len(base):
        raise ValueError(f"paired outcomes differ in length: ticket {len(ticket)}, base {len(base)}")
    if len(ticket) > cap:
        raise ValueError(f"{len(ticket)} pairs exceed the cap of {cap}")
    threshold, table = sequential_threshold(cap, alpha), _log_e_table(cap)
    wins = losses = pairs = 0
    best, decision, reason = 0.0, None, None
    for pairs, (t, b) in enumerate(zip(ticket, base, strict=True), 1):
        wins, losses = wins + (bool(t) and not b), losses + (bool(b) and not t)
        best = max(best, table[wins + losses][wins])
        if best >= threshold:
            decision, reason = "golden", "threshold reached"
        elif futility and futile(wins, losses, *futility):
            decision, reason = "not golden", "futile"
        elif table[wins + losses + cap - pairs][wins + cap - pairs] < threshold:
            decision, reason = "not golden", "cap reached" if pairs == cap else "out of reach"
        if decision:
            break
    return Sequential(pairs, wins, losses, float(np.exp(best)), float(np.exp(threshold)),
                      min(1.0, sequential_level(best, cap)), decision, reason)

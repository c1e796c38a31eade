"""Success rates with confidence intervals, and the paired test a ticket must pass vs. the base."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

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

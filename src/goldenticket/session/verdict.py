"""A complete session's verdict, typed: each confirm arm's `evaluation.VerdictRow` with the test
behind its p-value and its decision, and when and why the session stopped. JSON only through
`to_dict`, at the edge (summary.json, the server's answers)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from scipy.stats import fisher_exact

from goldenticket.session.race import BASE, FUTILITY, Plan
from goldenticket.stats import Rate, Sequential, holm_adjust, paired_exact_test, sequential_sign_test

if TYPE_CHECKING:
    from goldenticket.evaluation import VerdictRow

Confirmed = list[tuple[str, bool, str | None]]  # the scored confirm episodes' (arm, success, scene), in order
PAIRED, UNPAIRED = "paired exact McNemar (sign) test on scene ids", "Fisher's exact test, unpaired"


@dataclass(frozen=True)
class ArmVerdict:
    """One confirm arm: its row (success rate; for a finalist, the one-sided p-value against the
    base), and for a finalist the test that gave it and its decision ("golden" or "not golden":
    the plan's alpha or the sequential test decides, not `row.golden`)."""

    row: VerdictRow
    test: str | None = None
    decision: str | None = None

    @property
    def golden(self) -> bool:
        return self.decision == "golden"

    @property
    def rate(self) -> Rate:
        return self.row.rate

    def to_dict(self) -> dict:
        """The arm as summary.json writes it: the rate, then a finalist's p-value, test and
        decision (no non-finite count: a robot's episode has none)."""
        out = self.row.rate.to_dict()
        if self.test is None:
            return out
        return out | {"p_vs_base": self.row.p_vs_base, "test": self.test, "golden": self.golden,
                      "verdict": self.decision}


@dataclass(frozen=True)
class FixedStop:
    """Fixed stopping: all of the plan's `episodes` scored, p-values judged at `alpha`."""

    alpha: float
    episodes: int
    rule: ClassVar[str] = "fixed"
    reason: ClassVar[str] = "every planned episode scored"

    @property
    def why(self) -> str:
        return f"the fixed protocol: all {self.episodes} planned episodes scored"

    def to_dict(self) -> dict:
        return {"rule": self.rule, "alpha": self.alpha, "episodes": self.episodes, "reason": self.reason,
                "why": self.why}


@dataclass(frozen=True)
class SequentialStop:
    """Sequential stopping: the sign test after the last pair (`name`: paired by scene id or
    unpaired), its level, cap and futility stop (q1, beta), the episodes scored in all and the
    time of the last score."""

    test: Sequential
    name: str
    alpha: float
    cap: int
    episodes: int
    stopped_at: float | None
    futility: tuple[float, float] = FUTILITY
    rule: ClassVar[str] = "sequential"

    @property
    def reason(self) -> str:
        return "cap reached" if self.test.pairs == self.cap else "decided early"

    @property
    def why(self) -> str:
        test, (q1, beta), discordant = self.test, self.futility, self.test.ticket_only + self.test.base_only
        e, threshold = f"{test.e_value:.3g}", f"{test.threshold:.3g}"
        detail = {"threshold reached": f"the e-value reached {e} (threshold {threshold})",
                  "futile": f"the base won {test.base_only} of {discordant} discordant pairs: no difference "
                            f"is {1 / beta:g} or more times likelier than a ticket winning {q1:.0%} of them",
                  "out of reach": f"the e-value (at most {e} so far) cannot reach {threshold} within the cap",
                  "cap reached": f"the e-value stayed below {threshold} (at most {e})"}
        return (f"{self.reason} after {test.pairs} of at most {self.cap} pairs ({self.episodes} episodes in "
                f"all): {detail[test.reason]}; {test.decision}")

    def to_dict(self) -> dict:
        test, (q1, beta) = self.test, self.futility
        return {"rule": self.rule, "test": self.name, "alpha": self.alpha, "cap": self.cap,
                "threshold": test.threshold, "e_value": test.e_value, "futility": {"q1": q1, "beta": beta},
                "pairs": test.pairs, "ticket_only": test.ticket_only, "base_only": test.base_only,
                "episodes": self.episodes, "stopped_at": self.stopped_at, "reason": self.reason,
                "why": self.why}


@dataclass(frozen=True)
class SessionVerdict:
    """The confirm phase's arms (the base first), how the session stopped, and how to read the
    p-values."""

    arms: dict[str, ArmVerdict]
    stopping: FixedStop | SequentialStop
    note: str

    def rows(self) -> dict[str, dict]:
        """Each arm as summary.json writes it, as the verdict table and plot take them."""
        return {arm: verdict.to_dict() for arm, verdict in self.arms.items()}

    def to_dict(self) -> dict:
        return {"arms": self.rows(), "stopping": self.stopping.to_dict(), "note": self.note}


@dataclass(frozen=True)
class Pairs:
    """A sequential session's scored confirm pairs: the finalist, its and the base's outcomes,
    and whether each pair's two episodes name the same scene."""

    finalist: str | None
    ticket: list[bool]
    base: list[bool]
    by_scene: bool


def fixed_verdict(plan: Plan, confirmed: Confirmed) -> SessionVerdict:
    """Each finalist against the base: a paired exact test when scene ids pair its every episode
    with a base episode, else Fisher's exact test (unpaired), Holm-adjusted over the finalists."""
    scenes: dict[str, dict[str | None, bool]] = {}
    outcomes: dict[str, list[bool]] = {}
    for arm, success, scene in confirmed:
        scenes.setdefault(arm, {})[scene] = success
        outcomes.setdefault(arm, []).append(success)
    finalists = [arm for arm in outcomes if arm != BASE]
    tests = [_fixed_test(scenes[arm], scenes[BASE], outcomes[arm], outcomes[BASE]) for arm in finalists]
    arms = {BASE: ArmVerdict(_row(outcomes[BASE]))}
    for arm, (test, _), p in zip(finalists, tests, holm_adjust([p for _, p in tests]), strict=True):
        arms[arm] = ArmVerdict(_row(outcomes[arm], p), test, "golden" if p < plan.alpha else "not golden")
    used = " and ".join(sorted({test for test, _ in tests}))
    note = (f"p-values: {used}; one-sided, finalist better than base, Holm-adjusted over the 2 finalists; "
            f"'golden' means p < {plan.alpha:g}")
    return SessionVerdict(arms, FixedStop(plan.alpha, plan.episodes), note)


def confirm_pairs(confirmed: Confirmed, finalist: str | None) -> Pairs:
    """The complete pairs of a sequential session's scored confirm episodes."""
    pairs = [sorted(confirmed[i:i + 2], key=lambda r: r[0] == BASE) for i in range(0, len(confirmed) - 1, 2)]
    by_scene = all(a[2] is not None and a[2] == b[2] for a, b in pairs)
    return Pairs(finalist, [a[1] for a, _ in pairs], [b[1] for _, b in pairs], by_scene)


def sequential_test(plan: Plan, pairs: Pairs) -> Sequential:
    """The sequential sign test on the pairs scored so far."""
    return sequential_sign_test(pairs.ticket, pairs.base, plan.confirm, plan.alpha, FUTILITY)


def sequential_verdict(plan: Plan, pairs: Pairs, episodes: int, stopped_at: float | None) -> SessionVerdict:
    """The finalist against the base by the sequential sign test, and when and why it stopped
    (`episodes` scored in all, the last at `stopped_at`)."""
    test = sequential_test(plan, pairs)
    name = "sequential sign test, " + ("pairs matched by scene id" if pairs.by_scene else "unpaired episodes")
    arms = {BASE: ArmVerdict(_row(pairs.base)),
            pairs.finalist: ArmVerdict(_row(pairs.ticket, test.p_value), name, test.decision)}
    (q1, beta), threshold, cap, alpha = FUTILITY, f"{test.threshold:.3g}", plan.confirm, plan.alpha
    note = (f"p-value: the sequential sign test, one-sided, ticket better than base, tested after every pair "
            f"of the confirm phase; 'golden' means its mixture e-value reached {threshold}, which under no "
            f"difference happens within {cap} pairs with chance below {alpha:g} (p < {alpha:g}); not golden "
            f"early once out of reach, or futile (which stops a ticket that wins {q1:.0%} of the discordant "
            f"pairs with chance at most {beta:g})")
    return SessionVerdict(arms, SequentialStop(test, name, alpha, cap, episodes, stopped_at), note)


def _fixed_test(scenes: dict, base_scenes: dict, outcomes: list[bool], base: list[bool]) -> tuple[str, float]:
    """The test of one finalist against the base (`scenes`: outcomes by scene id), and its
    one-sided p-value, not adjusted."""
    paired = _pairs(scenes, base_scenes, len(outcomes), len(base))
    if paired:
        return PAIRED, paired_exact_test(*paired)
    table = [[sum(outcomes), len(outcomes) - sum(outcomes)], [sum(base), len(base) - sum(base)]]
    return UNPAIRED, float(fisher_exact(table, alternative="greater").pvalue)


def _pairs(arm: dict, base: dict, n_arm: int, n_base: int) -> tuple[list[bool], list[bool]] | None:
    """Outcomes paired by scene id, if every episode of both arms has one, each scene once per arm
    and the same scenes in both arms; else None."""
    if None in arm or None in base or len(arm) != n_arm or len(base) != n_base or set(arm) != set(base):
        return None
    scenes = sorted(arm)
    return [arm[s] for s in scenes], [base[s] for s in scenes]


def _row(outcomes: list[bool], p_vs_base: float | None = None) -> VerdictRow:
    """An arm's row; evaluation (with the rollout engine, torch) is imported once a verdict is due."""
    from goldenticket.evaluation import VerdictRow

    return VerdictRow(Rate.of(outcomes), p_vs_base=p_vs_base, successes=tuple(outcomes))

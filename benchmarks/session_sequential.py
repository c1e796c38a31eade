"""Real-robot sessions in simulation: sequential stopping and racing against the fixed protocol.

    python benchmarks/session_sequential.py    # ~6 min on 1 core the first time, ~30 s after

The robot is simulated two ways. Bernoulli arms: every episode succeeds independently with its
arm's rate. The bundled policies as the robot: each arm's true outcome on each of 200 held-out
Meta-World seeds, from real episodes (run once through the Engine and cached in the JSON); a
simulated episode draws a scene (a seed) and takes that arm's outcome there, and a pair of
confirm episodes shares its scene, as an operator who resets one scene for both runs would.

Two levels, both at the same alpha:
- the test alone: one ticket against the base, the fixed protocol's exact test on M = 50
  episodes per arm (Fisher's, or the paired exact test on scenes), no Holm correction, against
  the sequential sign test with its futility stop on at most 70 pairs;
- the whole session: N = 6 candidate tickets x K = 25 search episodes, one of them better than
  the base by the gain, the others as good as the base. Fixed: every candidate K episodes, the
  top 2 and the base 50 each, Holm over the two (300 episodes). Sequential: the race (at most
  150 episodes, fewer once one candidate is left), then its finalist and the base in pairs
  until the test decides (at most 70 pairs).
Power: the chance of calling a truly better ticket golden; false golden: of calling golden a
ticket no better than the base. Bernoulli arms: gains of 10, 20 and 40 points around 50%, and
from base rates of 20, 50 and 80% where the ticket's rate stays at most 100%. The simulators use
the session's own rules (goldenticket.session.race: the race's schedule and trails();
goldenticket.stats: the test and futile()); a check replays 300 simulated races through
race.race and 300 confirm phases through sequential_sign_test and requires the same
finalists, episodes and decisions.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from results_files import RESULTS, write_results
from scipy.stats import binom, fisher_exact

from goldenticket.config import DEFAULT_CONFIRM
from goldenticket.session.race import DROP_Z, FUTILITY, ROUND, Plan, race, trails
from goldenticket.stats import (
    futile,
    mixture_log_e,
    sequential_sign_test,
    sequential_threshold,
    wilson_interval,
)

ALPHA, SIMS, SEED = 0.05, 20_000, 2024
FIXED_M, CAP = DEFAULT_CONFIRM["fixed"], DEFAULT_CONFIRM["sequential"]
PLAN = Plan("simulated", "-", (1, 1), 6, 25, CAP, 0, "sequential", ALPHA)
GAINS = (0.1, 0.2, 0.4)
BASE_RATES = NULL_RATES = (0.2, 0.5, 0.8)
ROBOT = {"pick-place flow": ("metaworld/pick-place-v3/flow", "ac7033f127b8"),
         "drawer-open flow": ("metaworld/drawer-open-v3/flow", "c54d654a9844"),
         "window-open ddim@2": ("metaworld/window-open-v3/ddim@2", "3e03abfabd25")}
SEEDS = (400, 600)  # held-out seeds 400..599: after those the bundled tickets were judged and checked on


def real_outcomes(cached: dict) -> dict:
    """Base and ticket outcomes on SEEDS for each ROBOT pair, and a second base (another noise
    seed) for the first, as strings of 0/1; reused from `cached` when it holds the same spec."""
    import goldenticket
    from goldenticket.tasks import seeds_in


    spec = {"pairs": ROBOT, "seeds": SEEDS}
    if cached.get("spec") == json.loads(json.dumps(spec)):
        return cached
    start, seeds, outcomes = time.perf_counter(), seeds_in("heldout", SEEDS[1])[SEEDS[0]:], {}

    def bits(row) -> str:
        return "".join("01"[success] for success in row.successes)

    for i, (name, (policy, ticket_id)) in enumerate(ROBOT.items()):
        rows = goldenticket.evaluate(policy, tickets=[ticket_id], seeds=seeds, workers=1)
        outcomes[name] = {"base": bits(rows["base"]), "ticket": bits(rows[ticket_id])}
        if i == 0:
            again = goldenticket.evaluate(policy, tickets=[ticket_id], seeds=seeds, seed=1, workers=1)
            outcomes[name]["base again"] = bits(again["base"])
    return {"spec": spec, "outcomes": outcomes, "seconds": time.perf_counter() - start}


def vector(bits: str) -> np.ndarray:
    return np.array([b == "1" for b in bits], dtype=float)


class Simulator:
    """Sessions on arms given as success probabilities per scene (one scene: Bernoulli arms)."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.log_e = np.array([[mixture_log_e(w, n - w) if w <= n else np.nan for w in range(CAP + 1)]
                               for n in range(CAP + 1)])
        self.threshold = sequential_threshold(CAP, ALPHA)
        self.fisher = np.array([[fisher_exact([[t, FIXED_M - t], [b, FIXED_M - b]], "greater").pvalue
                                 for b in range(FIXED_M + 1)] for t in range(FIXED_M + 1)])
        self.replayed = self.raced = 0

    def outcomes(self, probs: np.ndarray, scenes: np.ndarray) -> np.ndarray:
        """One episode per scene index: probs (sims, S) or (S,), scenes (sims, n)."""
        p = probs[scenes] if probs.ndim == 1 else np.take_along_axis(probs, scenes, 1)
        return self.rng.random(scenes.shape) < p

    def scenes(self, size: int, shape: tuple[int, ...]) -> np.ndarray:
        return self.rng.integers(0, size, shape)

    def fixed_test(self, ticket: np.ndarray, base: np.ndarray, paired: bool) -> np.ndarray:
        """The fixed protocol's one-sided p-value per run: paired exact test, else Fisher's."""
        if paired:
            wins, losses = (ticket & ~base).sum(1), (base & ~ticket).sum(1)
            return np.where(wins + losses > 0, binom.sf(wins - 1, wins + losses, 0.5), 1.0)
        return self.fisher[ticket.sum(1), base.sum(1)]

    def sequential(self, ticket: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Golden or not, and pairs run, per run of at most CAP pairs (ticket, base: (sims, CAP))."""
        wins, losses = np.cumsum(ticket & ~base, 1), np.cumsum(base & ~ticket, 1)
        reached = self.log_e[wins + losses, wins] >= self.threshold
        left = CAP - np.arange(1, CAP + 1)
        hopeless = self.log_e[wins + losses + left, wins + left] < self.threshold
        hopeless |= futile(wins, losses, *FUTILITY)
        first = np.where(reached.any(1), reached.argmax(1), CAP)
        stop = np.minimum(first, np.where(hopeless.any(1), hopeless.argmax(1), CAP))
        golden, pairs = first <= stop, np.minimum(stop + 1, CAP)
        for i in range(min(300 - self.replayed, len(ticket))):  # what the session itself decides
            test = sequential_sign_test(ticket[i, :pairs[i]], base[i, :pairs[i]], CAP, ALPHA, FUTILITY)
            assert (test.decision == "golden", test.pairs) == (golden[i], pairs[i]), (i, test)
            self.replayed += 1
        return golden, pairs

    def race(self, play) -> tuple[np.ndarray, np.ndarray]:
        """The finalist and the search episodes per run of the session's race; play(each) gives
        `each` episodes of every candidate, (sims, N, each)."""
        alive, wins = np.ones((SIMS, PLAN.tickets), bool), np.zeros((SIMS, PLAN.tickets), int)
        used, runs, going, each, rounds = np.zeros(SIMS, int), 0, np.ones(SIMS, bool), PLAN.first_round, []
        while going.any():
            ran, outcomes = alive & going[:, None], play(each)
            rounds.append((ran, outcomes))
            wins += (outcomes & ran[..., None]).sum(2)
            used, runs = used + ran.sum(1) * each, runs + going * each
            lead = np.where(alive, wins, -1).max(1, keepdims=True)
            alive &= ~(going[:, None] & trails(lead, wins, np.maximum(runs, 1)[:, None]))
            each, left = ROUND, alive.sum(1)
            going &= (left > 1) & (used + left * ROUND <= PLAN.tickets * PLAN.episodes_per_ticket)
        finalist = np.where(alive, wins, -1).argmax(1)  # ties: the earlier candidate
        names = [str(i) for i in range(PLAN.tickets)]
        for i in range(min(300 - self.raced, SIMS)):  # what the session itself plans
            search = [(names[j], bool(o)) for ran, outcomes in rounds for j in np.flatnonzero(ran[i])
                      for o in outcomes[i, j]]
            replay = race(PLAN, names, search)
            assert (replay.alive[0], replay.next_round, len(search)) == (names[finalist[i]], 0, used[i]), i
            self.raced += 1
        return finalist, used

    def tests_alone(self, ticket: np.ndarray, base: np.ndarray) -> dict:
        """One ticket against the base: the fixed test on FIXED_M per arm, the sequential on CAP pairs."""
        paired = len(base) > 1
        scenes = self.scenes(len(base), (SIMS, FIXED_M))
        other = scenes if paired else self.scenes(len(base), (SIMS, FIXED_M))
        fixed = self.fixed_test(self.outcomes(ticket, scenes), self.outcomes(base, other), paired) < ALPHA
        scenes = self.scenes(len(base), (SIMS, CAP))
        golden, pairs = self.sequential(self.outcomes(ticket, scenes), self.outcomes(base, scenes))
        return {"fixed": {"golden": fixed, "episodes": np.full(SIMS, 2 * FIXED_M)},
                "sequential": {"golden": golden, "episodes": 2 * pairs}}

    def sessions(self, good: np.ndarray, base: np.ndarray) -> dict:
        """Whole sessions: one candidate `good`, the others as good as the base, at random places."""
        n, s, k, rows = PLAN.tickets, len(base), PLAN.episodes_per_ticket, np.arange(SIMS)[:, None]
        better = np.arange(n) == self.rng.integers(0, n, SIMS)[:, None]  # (sims, N): the good candidate
        truly = better & (good.mean() > base.mean())

        def play(which: np.ndarray, scenes: np.ndarray) -> np.ndarray:
            """Episodes on `scenes` of candidates that are the good one where `which`."""
            return self.rng.random(scenes.shape) < np.where(which[..., None], good[scenes], base[scenes])

        # fixed: K each, then the top 2 and the base FIXED_M each (paired by scene on real arms), Holm
        top = np.argsort(-play(better, self.scenes(s, (SIMS, n, k))).sum(2), 1, kind="stable")[:, :2]
        scenes = self.scenes(s, (SIMS, FIXED_M))
        base_runs = self.outcomes(base, scenes)
        p = np.stack([self.fixed_test(play(better[rows[:, 0], top[:, j]], scenes if s > 1 else
                                           self.scenes(s, (SIMS, FIXED_M))), base_runs, s > 1)
                      for j in range(2)], 1)
        chosen, fixed_golden = top[rows[:, 0], p.argmin(1)], 2 * p.min(1) < ALPHA
        # sequential: the race, then its finalist and the base in pairs sharing a scene
        finalist, used = self.race(lambda each: play(better, self.scenes(s, (SIMS, n, each))))
        scenes = self.scenes(s, (SIMS, CAP))
        golden, pairs = self.sequential(play(better[rows[:, 0], finalist], scenes),
                                        self.outcomes(base, scenes))
        return {"fixed": {"golden": fixed_golden, "true": fixed_golden & truly[rows[:, 0], chosen],
                          "episodes": np.full(SIMS, n * k + 3 * FIXED_M)},
                "sequential": {"golden": golden, "true": golden & truly[rows[:, 0], finalist],
                               "episodes": used + 2 * pairs}}


def summary(runs: dict, key: str) -> dict:
    """The rate of `key` (false golden, or power) with its Wilson interval, and the mean operator
    episodes to a verdict."""
    hits = int(runs[key].sum())
    low, high = wilson_interval(hits, len(runs[key]))
    return {"rate": hits / len(runs[key]), "ci": [low, high], "episodes": float(runs["episodes"].mean())}


def scenarios(record: dict) -> list[tuple[str, str, float, np.ndarray, np.ndarray]]:
    """(name, robot, true gain, ticket probs, base probs): Bernoulli and real, nulls first."""
    out = [(f"no difference, {rate:.0%}", "bernoulli", 0.0, np.array([rate]), np.array([rate]))
           for rate in NULL_RATES]
    real = record["outcomes"]
    first = real[next(iter(ROBOT))]
    out.append((f"no difference, {next(iter(ROBOT))} base twice", "bundled", 0.0,
                vector(first["base again"]), vector(first["base"])))
    pairs = [(0.5 - gain / 2, gain) for gain in GAINS]  # around 50%, then from each base rate
    pairs += [(rate, gain) for rate in BASE_RATES for gain in GAINS if round(rate + gain, 9) <= 1]
    out += [(f"+{gain:.0%}, {rate:.0%} vs {rate + gain:.0%}", "bernoulli", gain,
             np.array([min(1.0, rate + gain)]), np.array([rate])) for rate, gain in pairs]
    for name, arms in real.items():
        ticket, base = vector(arms["ticket"]), vector(arms["base"])
        out.append((f"{name}, {base.mean():.0%} vs {ticket.mean():.0%}", "bundled",
                    ticket.mean() - base.mean(), ticket, base))
    return out


def study(record: dict) -> list[dict]:
    sim, rows = Simulator(np.random.default_rng(SEED)), []
    for name, robot, gain, ticket, base in scenarios(record):
        alone, whole = sim.tests_alone(ticket, base), sim.sessions(ticket, base)
        row = {"scenario": name, "robot": robot, "gain": gain,
               "test": {rule: summary(runs, "golden") for rule, runs in alone.items()},
               "session": {rule: summary(runs, "true" if gain > 0 else "golden")
                           for rule, runs in whole.items()}}
        rows.append(row)
        print(f"{name}: {json.dumps(row)}", flush=True)
    assert sim.replayed == sim.raced == 300
    return rows


def saving(row: dict, level: str) -> float:
    return 1 - row[level]["sequential"]["episodes"] / row[level]["fixed"]["episodes"]


def kept(row: dict) -> bool:
    """Whether a whole sequential session is at least as powerful as a fixed one."""
    return row["session"]["sequential"]["rate"] >= row["session"]["fixed"]["rate"]


def markdown(rows: list[dict], wall: dict) -> str:
    def rate(r: dict) -> str:
        return f"{r['rate']:.1%} [{r['ci'][0]:.1%}, {r['ci'][1]:.1%}]"

    lines = ["| scenario | robot | level | fixed: rate | fixed: episodes | sequential: rate | "
             "sequential: episodes | fewer episodes |", "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        for level in ("test", "session"):
            f, s = row[level]["fixed"], row[level]["sequential"]
            lines.append(f"| {row['scenario']} | {row['robot']} | {level} | {rate(f)} | "
                         f"{f['episodes']:.0f} | {rate(s)} | {s['episodes']:.1f} | "
                         f"{saving(row, level):.0%} |")
    nulls = [r for r in rows if r["gain"] == 0]
    worst = max(r[level]["sequential"]["rate"] for r in nulls for level in ("test", "session"))
    target = [(r["scenario"], saving(r, "session"), kept(r)) for r in rows if round(r["gain"], 2) >= 0.2]
    held = [t for t in target if t[1] >= 0.3 and t[2]]
    lines += ["", "- Rate: false golden under no difference, else power (a truly better ticket called "
              f"golden), with its 95% Wilson interval, over {SIMS} simulated runs each; alpha = {ALPHA}.",
              f"- False golden under no difference: at most {worst:.2%} for the sequential protocol "
              f"(alpha {ALPHA}).",
              "- Target (whole sessions, >= 30% fewer operator episodes at equal or better power, gain >= 20 "
              f"points): met in {len(held)} of {len(target)} cases: " + "; ".join(
                  f"{name}: {cut:.0%} fewer, power {'kept' if ok else 'lower'}" for name, cut, ok in target)
              + ".",
              "- test: one ticket against the base, fixed = the exact test on 50 episodes per arm (no Holm), "
              f"sequential = the sign test on at most {CAP} pairs with its futility stop (q1 = "
              f"{FUTILITY[0]}, beta = {FUTILITY[1]}). session: 6 tickets x 25 search episodes with one "
              "better ticket; fixed = 150 search + 3 x 50 confirm with Holm; sequential = the race (every "
              f"candidate {PLAN.first_round} episodes, then {ROUND} more per round for each one still in, "
              f"dropped once it trails the leader by {DROP_Z} standard errors; at most 150 episodes) + at "
              f"most {CAP} pairs.",
              f"- Wall time: real episodes {wall['episodes']:.0f} s (run once, then cached in the JSON), "
              f"simulation {wall['simulation']:.0f} s, on 1 core."]
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 8))
    axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.25, 1, 0.8]})
    gains = [r for r in rows if r["gain"] > 0]
    labels = [r["scenario"] for r in gains]
    y = np.arange(len(gains))
    for ax, level in zip(axes[:2], ("session", "test"), strict=True):
        for shift, rule, color in ((-0.18, "fixed", "#777777"), (0.18, "sequential", "#d4a017")):
            ax.barh(y + shift, [r[level][rule]["episodes"] for r in gains], 0.34, color=color, label=rule)
            for yi, r in zip(y, gains, strict=True):
                s = r[level][rule]
                ax.annotate(f"power {s['rate']:.1%}", (s["episodes"], yi + shift),
                            xytext=(3, -3), textcoords="offset points", fontsize=7)
        ax.set_yticks(y, labels if level == "session" else [""] * len(y), fontsize=8)
        ax.set_xlabel("mean operator episodes to a verdict")
        ax.set_title({"session": "whole session (race + confirm)",
                      "test": "the test alone (1 ticket vs base)"}[level])
        ax.set_xlim(0, 1.35 * max(r[level]["fixed"]["episodes"] for r in gains))
        ax.invert_yaxis()
        ax.legend(loc="upper right", fontsize=8, ncols=2)
    nulls = [r for r in rows if r["gain"] == 0]
    ax = axes[2]
    marks = [(-0.27, "test", "fixed", "#bbbbbb"), (-0.09, "test", "sequential", "#f2d27a"),
             (0.09, "session", "fixed", "#777777"), (0.27, "session", "sequential", "#d4a017")]
    for i, r in enumerate(nulls):
        for shift, level, rule, color in marks:
            s = r[level][rule]
            ax.errorbar(s["rate"], i + shift, xerr=[[s["rate"] - s["ci"][0]], [s["ci"][1] - s["rate"]]],
                        fmt="o", color=color, label=f"{rule}, {level}" if i == 0 else None, ms=4)
    ax.axvline(ALPHA, color="red", ls="--", lw=1, label=f"alpha = {ALPHA}")
    names = [r["scenario"].removeprefix("no difference, ").replace(" base", "\nbase") for r in nulls]
    ax.set_yticks(range(len(nulls)), names, fontsize=8)
    ax.set_xlabel("false golden rate (95% Wilson)")
    ax.set_xlim(0, 1.6 * ALPHA)
    ax.set_title("no difference: false golden")
    ax.invert_yaxis()
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    path = RESULTS / "session_sequential.json"
    cached = json.loads(path.read_text()).get("robot", {}) if path.is_file() else {}
    robot = real_outcomes(cached)
    start = time.perf_counter()
    rows = study(robot)
    wall = {"episodes": robot["seconds"], "simulation": time.perf_counter() - start}
    record = {"alpha": ALPHA, "sims": SIMS, "seed": SEED, "fixed_m": FIXED_M, "cap": CAP,
              "plan": {"tickets": PLAN.tickets, "episodes_per_ticket": PLAN.episodes_per_ticket},
              "race": {"first_round": PLAN.first_round, "round": ROUND, "drop_z": DROP_Z},
              "futility": {"q1": FUTILITY[0], "beta": FUTILITY[1]},
              "threshold": math.exp(sequential_threshold(CAP, ALPHA)),
              "rows": rows, "wall_seconds": wall, "robot": robot}
    write_results("session_sequential", record, markdown(rows, wall), lambda p: plot(rows, p))
    print(f"Wall time: real episodes {wall['episodes']:.0f} s, simulation {wall['simulation']:.0f} s")


if __name__ == "__main__":
    main()

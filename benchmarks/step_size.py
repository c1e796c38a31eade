"""Starts: how wide the first tickets should be, and where, where noise helps and where it hurts.

    python benchmarks/step_size.py    # resumable; writes benchmarks/results/step_size.{md,json,png}

CMA-ES (population 20, 20 search seeds) from w = 0 with initial step sizes 1 (as wide as the
policy's own Gaussian noise), 0.5, 0.25 and 1.5, and from a random-search stage ("rs+S": RS_STAGE
N(0, I) tickets, then CMA-ES from the best of them with step size S for the rest of the budget),
on six bundled pairs: three where tickets far from zero help (the zero ticket is no better than the
base) and three where noise hurts (the zero ticket beats the base). Each search spends BUDGET
episodes; as in `search`, its 3 x top_k best tickets and the zero ticket run on VALIDATION seeds and
the best there is the delivered ticket, rolled out on HELDOUT held-out seeds beside the base and the
zero ticket. Those seeds (from 1001000) are apart from the ones the existence table judges on.
Resumable: each pair's episodes share a run store.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from results_files import RESULTS, write_results

from goldenticket.config import EngineOptions, SearchConfig
from goldenticket.evaluation import BASE, ZERO, Arm, Evaluator, judge
from goldenticket.job import Plan, search_only, stages
from goldenticket.job.stages import search_evaluate
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import identity, load_policy
from goldenticket.report import rate_text
from goldenticket.stats import paired_exact_test
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in
from goldenticket.ticket_search import SearchResult, make_optimizer, run_search
from goldenticket.tickets import Ticket, TicketRecord, zero_ticket

HERE = Path(__file__).parent
NOISE_HELPS = ("reach-v3/ddim@2", "drawer-open-v3/flow", "peg-insert-side-v3/ddim@2")
NOISE_HURTS = ("window-open-v3/ddim@2", "pick-place-v3/ddim@2", "drawer-open-v3/ddim@2")
STARTS = ("1.0", "0.5", "0.25", "1.5", "rs+0.5", "rs+1.0")
RS_STAGE = 20  # random tickets before an "rs+S" start's CMA-ES: one CMA-ES population
BUDGET, VALIDATION, HELDOUT, FIRST_HELDOUT = 850, 40, 200, 1000
DEFAULTS = SearchConfig("", "")


def label(start: str) -> str:
    return f"RS, then step {start[3:]}" if start.startswith("rs+") else f"step {start}"


def search(evaluator: Evaluator, name: str, policy, start: str) -> SearchResult:
    """A `BUDGET`-episode search from `start`: the job's CMA-ES from w = 0 with that step size, or
    "rs+S": RS_STAGE random tickets, then CMA-ES from the best of them with step size S, both
    drawing from one generator (a procedure the job does not offer)."""
    if not start.startswith("rs+"):
        return search_only(searching(name, sigma_init=float(start)), evaluator, policy)
    seeds, rng = seeds_in("search", DEFAULTS.search_seeds), np.random.default_rng(DEFAULTS.seed)
    evaluate, shape = search_evaluate(evaluator, identity(policy)), policy.noise_shape

    def run(method: str, budget: int, **params) -> SearchResult:
        return run_search(make_optimizer(method, shape, seeds, rng, **params), evaluate, budget=budget,
                          stop_after_perfect=DEFAULTS.stop_after_perfect)

    stage = run("rs", BUDGET, batch_size=RS_STAGE, num_tickets=RS_STAGE)
    if stage.stopped_because == "k perfect tickets":
        return stage
    best = stage.top(1)[0].ticket
    rest = run("cma-es", BUDGET - stage.episodes_used, sigma_init=float(start[3:]), mean=best)
    return SearchResult(stage.candidates + rest.candidates, stage.episodes_used + rest.episodes_used,
                        rest.stopped_because)


def searching(name: str, **settings) -> SearchConfig:
    """The search over the full ticket, CMA-ES with `settings`, every ticket on every search seed."""
    return replace(DEFAULTS, policy=name, task=name.rsplit("/", 1)[0], budget=BUDGET, method="cma-es",
                   subspace="full", optimizer=settings, validation_seeds=VALIDATION, halving=False)


def delivered(evaluator: Evaluator, name: str, policy, start: str) -> tuple[Ticket, bool]:
    """The ticket a search from `start` delivers after validation (the job's: the best of its top
    3 x top_k and the zero ticket on the validation seeds), and whether it is the zero ticket."""
    plan = Plan.of(searching(name), policy, [evaluator.engine.task])
    result = search(evaluator, name, policy, start)
    found_for = TicketRecord(policy_fingerprint=identity(policy))
    top = [Ticket(c.ticket, found_for) for c in stages.top_candidates(plan, result)]
    zero = Ticket(zero_ticket(policy.noise_shape).noise, found_for)
    best = stages.validate(plan, evaluator, [*top, zero], top_k=1).chosen[0]
    return best, best.id == zero.id


def study(pair: str, runs: Path, workers: int) -> dict:
    name = f"metaworld/{pair}"
    policy, task = load_policy(name), get_task(name.rsplit("/", 1)[0])
    heldout = seeds_in("heldout", FIRST_HELDOUT + HELDOUT)[FIRST_HELDOUT:]
    out = {"helps": pair in NOISE_HELPS}
    with RunStore(runs / f"{pair.replace('/', '_')}.sqlite") as store, \
            Evaluator.open(name, task, EngineOptions(workers=workers), store, loaded=policy) as evaluator:
        picks = {start: delivered(evaluator, name, policy, start) for start in STARTS}
        sources = {ZERO: Constant(zero_ticket(policy.noise_shape).noise)}
        sources |= {Arm.ticket(t.id): Constant(t.noise) for t, _ in picks.values()}
        rows = judge(evaluator, sources, heldout, Gaussian(DEFAULTS.seed)).rows
    out |= {arm.key: rows[arm].to_dict() for arm in (BASE, ZERO)}
    out["starts"] = {}
    for start, (t, is_zero) in picks.items():
        mine = rows[Arm.ticket(t.id)]
        below = {f"p_below_{arm.key}": paired_exact_test(rows[arm].successes, mine.successes)
                 for arm in (BASE, ZERO)}
        out["starts"][start] = mine.to_dict() | {"ticket": t.id, "is_zero": is_zero} | below
    return out


def markdown(results: dict, wall: float) -> str:
    lines = [f"Regenerate: `python benchmarks/step_size.py` ({wall / 60:.0f} min here, 2 workers).", "",
             "| pair | noise | base | zero ticket | " + " | ".join(map(label, STARTS)) + " |",
             "|---|---|---|---|" + "---|" * len(STARTS)]
    for pair, r in results.items():
        cells = [rate_text(row) + (" (zero)" if row["is_zero"] else "") + (" *" if below(row) else "")
                 for row in (r["starts"][s] for s in STARTS)]
        lines.append(f"| {pair} | {'helps' if r['helps'] else 'hurts'} | {rate_text(r['base'])} | "
                     f"{rate_text(r['zero'])} | " + " | ".join(cells) + " |")
    lines += ["", f"Mean over the pairs: base {mean(results, 'base'):.1%}, zero ticket "
              f"{mean(results, 'zero'):.1%}, "
              + ", ".join(f"{label(s)}: {mean(results, s):.1%}" for s in STARTS) + ".",
              f"Each cell: the ticket a search of {BUDGET} episodes from that start delivers after "
              f"validation on {VALIDATION} seeds (\"(zero)\": the zero ticket won validation), on {HELDOUT} "
              f"held-out seeds from {seeds_in('heldout', FIRST_HELDOUT + 1)[-1]}; step S: CMA-ES from w = 0 "
              f"with step size S; RS, then step S: {RS_STAGE} random tickets, then CMA-ES from the best of "
              "them with step size S; *: significantly below the base or the zero ticket (one-sided exact "
              "paired test, p < 0.05)."]
    return "\n".join(lines) + "\n"


def below(row: dict) -> bool:
    return min(row["p_below_base"], row["p_below_zero"]) < 0.05


def rate(r: dict, arm: str) -> float:
    """The success rate of `arm` ("base", "zero" or a start) in one pair's results."""
    return (r["starts"][arm] if arm in r["starts"] else r[arm])["success_rate"]


def mean(results: dict, arm: str) -> float:
    return float(np.mean([rate(r, arm) for r in results.values()]))


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 5))
    ax = fig.subplots()
    x = np.arange(len(results))
    arms = ("base", "zero", *STARTS)
    width = 0.8 / len(arms)
    for i, arm in enumerate(arms):
        ax.bar(x + (i - len(arms) / 2 + 0.5) * width, [rate(r, arm) for r in results.values()], width,
               label={"base": "base", "zero": "zero ticket"}.get(arm) or label(arm))
    ax.set_xticks(x, [f"{p.replace('-v3', '')}\n(noise {'helps' if r['helps'] else 'hurts'})"
                      for p, r in results.items()], fontsize="small")
    ax.set(ylabel=f"success on {HELDOUT} held-out seeds", ylim=(0, 1),
           title=f"Delivered ticket by start ({BUDGET} search episodes + validation)")
    ax.legend(fontsize="small", ncols=4, loc="upper center", bbox_to_anchor=(0.5, -0.14))
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=HERE / "runs" / "step_size")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--plot-only", action="store_true", help="redraw step_size.png from step_size.json")
    args = parser.parse_args()
    if args.plot_only:
        plot(json.loads((RESULTS / "step_size.json").read_text())["results"], RESULTS / "step_size.png")
        return
    args.runs.mkdir(parents=True, exist_ok=True)
    start, results = time.perf_counter(), {}
    for pair in NOISE_HELPS + NOISE_HURTS:
        results[pair] = study(pair, args.runs, args.workers)
        print(pair, {s: r["success_rate"] for s, r in results[pair]["starts"].items()}, flush=True)
    wall = time.perf_counter() - start
    settings = {"starts": STARTS, "rs_stage": RS_STAGE, "budget": BUDGET, "validation": VALIDATION,
                "heldout": HELDOUT, "first_heldout": FIRST_HELDOUT}
    write_results("step_size", {"settings": settings, "results": results, "wall_seconds": wall},
                  markdown(results, wall), lambda path: plot(results, path))


if __name__ == "__main__":
    main()

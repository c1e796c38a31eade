"""Step size: how wide the first tickets around w = 0 should be, where noise helps and where it hurts.

    python benchmarks/step_size.py    # resumable; writes benchmarks/results/step_size.{md,json,png}

CMA-ES (population 20, 20 search seeds) from w = 0 with initial step sizes 1 (as wide as the
policy's own Gaussian noise), 0.5 and 0.25, on six bundled pairs: three where tickets far from zero
help (the zero ticket is no better than the base) and three where noise hurts (the zero ticket beats
the base). Each search spends BUDGET episodes; as in `search`, its 3 x top_k best tickets and the
zero ticket run on VALIDATION seeds and the best there is the delivered ticket, rolled out on
HELDOUT held-out seeds beside the base and the zero ticket. Those seeds (from 1001000) are apart
from the ones the existence table judges on. Resumable: each pair's episodes share a run store.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from results_files import RESULTS, write_results

from goldenticket.config import EngineOptions, SearchConfig
from goldenticket.evaluation import Evaluator, judge
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import load_policy
from goldenticket.report import rate_text
from goldenticket.stats import paired_exact_test
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in
from goldenticket.ticket_search import make_optimizer, run_search
from goldenticket.tickets import Ticket, zero_ticket
from goldenticket.workflow import query_evaluator

HERE = Path(__file__).parent
NOISE_HELPS = ("reach-v3/ddim@2", "drawer-open-v3/flow", "peg-insert-side-v3/ddim@2")
NOISE_HURTS = ("window-open-v3/ddim@2", "pick-place-v3/ddim@2", "drawer-open-v3/ddim@2")
STEP_SIZES = (1.0, 0.5, 0.25)
BUDGET, VALIDATION, HELDOUT, FIRST_HELDOUT = 850, 40, 200, 1000
DEFAULTS = SearchConfig("", "")


def delivered(evaluator: Evaluator, policy, step: float) -> tuple[Ticket, bool]:
    """The ticket a `BUDGET`-episode search from step size `step` delivers after validation, and
    whether it is the zero ticket."""
    fingerprint, shape = policy.fingerprint(), policy.noise_shape
    search = seeds_in("search", DEFAULTS.search_seeds)
    optimizer = make_optimizer("cma-es", shape, search, np.random.default_rng(DEFAULTS.seed), sigma_init=step)
    result = run_search(optimizer, query_evaluator(evaluator, fingerprint), budget=BUDGET,
                        stop_after_perfect=DEFAULTS.stop_after_perfect)
    top = result.top(3 * DEFAULTS.top_k, min_episodes=len(search)) or result.top(3 * DEFAULTS.top_k)
    zero = Ticket(zero_ticket(shape).noise, {"policy_fingerprint": fingerprint})
    tickets = [Ticket(c.ticket, {"policy_fingerprint": fingerprint}) for c in top] + [zero]
    runs = evaluator.run([(t.id, Constant(t.noise), seeds_in("validation", VALIDATION)) for t in tickets])
    best = int(np.argmax([np.mean([r.ret for r in results]) for results in runs]))  # ties: search rank
    return tickets[best], tickets[best].id == zero.id


def study(pair: str, runs: Path, workers: int) -> dict:
    name = f"metaworld/{pair}"
    policy, task = load_policy(name), get_task(name.rsplit("/", 1)[0])
    heldout = seeds_in("heldout", FIRST_HELDOUT + HELDOUT)[FIRST_HELDOUT:]
    out = {"helps": pair in NOISE_HELPS}
    with RunStore(runs / f"{pair.replace('/', '_')}.sqlite") as store, \
            Evaluator.open(name, task, EngineOptions(workers=workers), store, loaded=policy) as evaluator:
        picks = {step: delivered(evaluator, policy, step) for step in STEP_SIZES}
        sources = {"zero": Constant(zero_ticket(policy.noise_shape).noise)}
        sources |= {t.id: Constant(t.noise) for t, _ in picks.values()}
        judged = judge(evaluator, sources, heldout, Gaussian(DEFAULTS.seed))
    out |= {arm: judged[arm].row().to_dict() for arm in ("base", "zero")}
    out["steps"] = {}
    for step, (t, is_zero) in picks.items():
        below = {f"p_below_{arm}": paired_exact_test(judged[arm].successes, judged[t.id].successes)
                 for arm in ("base", "zero")}
        out["steps"][str(step)] = judged[t.id].row().to_dict() | {"ticket": t.id, "is_zero": is_zero} | below
    return out


def markdown(results: dict, wall: float) -> str:
    head = " | ".join(f"step {s}" for s in STEP_SIZES)
    lines = [f"Regenerate: `python benchmarks/step_size.py` ({wall / 60:.0f} min here, 2 workers).", "",
             f"| pair | noise | base | zero ticket | {head} |",
             "|---|---|---|---|" + "---|" * len(STEP_SIZES)]
    for pair, r in results.items():
        cells = [rate_text(r["steps"][str(s)]) + (" (zero)" if r["steps"][str(s)]["is_zero"] else "")
                 + (" *" if below(r["steps"][str(s)]) else "") for s in STEP_SIZES]
        lines.append(f"| {pair} | {'helps' if r['helps'] else 'hurts'} | {rate_text(r['base'])} | "
                     f"{rate_text(r['zero'])} | " + " | ".join(cells) + " |")
    lines += ["", f"Mean over the pairs: base {mean(results, 'base'):.1%}, zero ticket "
              f"{mean(results, 'zero'):.1%}, "
              + ", ".join(f"step {s}: {mean(results, str(s)):.1%}" for s in STEP_SIZES) + ".",
              f"Each cell: the ticket a CMA-ES search of {BUDGET} episodes from that step size delivers "
              f"after validation on {VALIDATION} seeds (\"(zero)\": the zero ticket won validation), on "
              f"{HELDOUT} held-out seeds from {seeds_in('heldout', FIRST_HELDOUT + 1)[-1]}; *: significantly "
              "below the base or the zero ticket (one-sided exact paired test, p < 0.05)."]
    return "\n".join(lines) + "\n"


def below(row: dict) -> bool:
    return min(row["p_below_base"], row["p_below_zero"]) < 0.05


def mean(results: dict, arm: str) -> float:
    return float(np.mean([(r["steps"][arm] if arm in r["steps"] else r[arm])["success_rate"]
                          for r in results.values()]))


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.8))
    ax = fig.subplots()
    x = np.arange(len(results))
    arms = ("base", "zero", *map(str, STEP_SIZES))
    width = 0.8 / len(arms)
    for i, arm in enumerate(arms):
        rates = [(r["steps"][arm] if arm in r["steps"] else r[arm])["success_rate"] for r in results.values()]
        label = {"base": "base", "zero": "zero ticket"}.get(arm, f"step size {arm}")
        ax.bar(x + (i - len(arms) / 2 + 0.5) * width, rates, width, label=label)
    ax.set_xticks(x, [f"{p.replace('-v3', '')}\n(noise {'helps' if r['helps'] else 'hurts'})"
                      for p, r in results.items()], fontsize="small")
    ax.set(ylabel=f"success on {HELDOUT} held-out seeds", ylim=(0, 1),
           title=f"Delivered ticket by CMA-ES step size ({BUDGET} search episodes + validation)")
    ax.legend(fontsize="small", ncols=5, loc="upper center", bbox_to_anchor=(0.5, -0.14))
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
        print(pair, {s: r["success_rate"] for s, r in results[pair]["steps"].items()}, flush=True)
    wall = time.perf_counter() - start
    settings = {"step_sizes": STEP_SIZES, "budget": BUDGET, "validation": VALIDATION, "heldout": HELDOUT,
                "first_heldout": FIRST_HELDOUT}
    write_results("step_size", {"settings": settings, "results": results, "wall_seconds": wall},
                  markdown(results, wall), lambda path: plot(results, path))


if __name__ == "__main__":
    main()

"""Budget curves: held-out success of each method's best-so-far ticket against search episodes.

    python benchmarks/search_methods.py       # writes benchmarks/results/search_methods.{md,json,png}

Every search method on four bundled flow policies whose base success is at most 85%, from 100 to
5000 search episodes on 20 search seeds (the `search` defaults), one run per method and policy:
RS (20 tickets per batch), CEM, ZOS (10 candidates per step), CEM + racing, CEM + confidence-bound
racing and CMA-ES (populations of 20), and CEM + racing on the tie-broken objective
`success-progress`. At each checkpoint the search is replayed from its seed with that budget
(recorded episodes are read back, not re-run) and its best ticket by search score is rolled out on
100 held-out seeds. The second row of the plot puts every judged ticket's search score beside its
held-out success: the regression to the mean that the choice of a ticket must survive.
Resumable: the episodes of one policy and objective share a run store under `--runs`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from results_files import write_results

from goldenticket.config import EngineOptions, SearchConfig
from goldenticket.evaluation import Evaluator
from goldenticket.job import search_only
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import identity, load_policy
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in
from goldenticket.tickets import Ticket, TicketRecord

HERE = Path(__file__).parent
POLICIES = ("metaworld/pick-place-v3/flow", "metaworld/reach-v3/flow", "metaworld/drawer-open-v3/flow",
            "metaworld/push-v3/flow")
# label -> (method, hyper-parameters, objective)
METHODS = {"rs": ("rs", {"batch_size": 20}, "success"), "cem": ("cem", {"population": 20}, "success"),
           "zos": ("zos", {"candidates": 10}, "success"),
           "cem-racing": ("cem-racing", {"population": 20}, "success"),
           "cem-bounds": ("cem-bounds", {"population": 20}, "success"),
           "cma-es": ("cma-es", {"population": 20}, "success"),
           "cem-racing, success-progress": ("cem-racing", {"population": 20}, "success-progress")}
CHECKPOINTS = (100, 200, 500, 1000, 2000, 5000)  # search episodes
SEARCH_SEEDS, HELDOUT = 20, 100


def best_at(evaluator: Evaluator, policy_name: str, policy, label: str, budget: int) -> tuple[Ticket, float]:
    """The best ticket (and its search success) a search with this budget ends with, replayed
    from seed 0 (the job's search over every entry of the ticket, no early stop)."""
    method, params, objective = METHODS[label]
    cfg = SearchConfig(policy_name, evaluator.engine.task.name, method, budget, seed=0, optimizer=params,
                       search_seeds=SEARCH_SEEDS, subspace="full", objective=objective,
                       stop_after_perfect=None, halving=False)
    result = search_only(cfg, evaluator, policy)
    top = (result.top(1, min_episodes=SEARCH_SEEDS) or result.top(1))[0]
    ticket = Ticket(top.ticket, TicketRecord(policy_fingerprint=identity(policy)))
    return ticket, float(np.mean(top.successes))


def held_out(evaluator: Evaluator, ticket: Ticket | None) -> float:
    label, source = ("base", Gaussian(0)) if ticket is None else (ticket.id, Constant(ticket.noise))
    results = evaluator.run([(label, source, seeds_in("heldout", HELDOUT))])[0]
    return float(np.mean([r.success for r in results]))


def compare(policy_name: str, runs: Path, workers: int) -> dict:
    """{"base": rate, label: [{"budget", "search", "heldout"} per checkpoint]}."""
    task, policy = get_task(policy_name.rsplit("/", 1)[0]), load_policy(policy_name)
    out = {}
    for objective in dict.fromkeys(o for _, _, o in METHODS.values()):
        with RunStore(runs / f"{policy_name.replace('/', '_')}_{objective}.sqlite") as store, \
                Evaluator.open(policy_name, task, EngineOptions(workers=workers), store, objective,
                               policy) as evaluator:
            out.setdefault("base", held_out(evaluator, None))
            for label in [k for k, (_, _, o) in METHODS.items() if o == objective]:
                out[label] = []
                for budget in CHECKPOINTS:
                    ticket, search = best_at(evaluator, policy_name, policy, label, budget)
                    out[label].append({"budget": budget, "search": search,
                                       "heldout": held_out(evaluator, ticket)})
                print(f"{policy_name} {label}: held-out {[p['heldout'] for p in out[label]]}", flush=True)
    return out


def winners(results: dict) -> list[tuple[str, float]]:
    """Per checkpoint, the method with the highest mean held-out success over policies, with that mean."""
    means = {m: np.mean([[p["heldout"] for p in r[m]] for r in results.values()], axis=0) for m in METHODS}
    best = [max(METHODS, key=lambda m: means[m][i]) for i in range(len(CHECKPOINTS))]
    return [(m, float(means[m][i])) for i, m in enumerate(best)]


def shrinkage(results: dict) -> float:
    """Mean of (search score - held-out success) over every judged ticket: the optimism of selection."""
    gaps = [p["search"] - p["heldout"] for r in results.values() for m in METHODS for p in r[m]]
    return float(np.mean(gaps))


def markdown(results: dict, wall: float) -> str:
    head = " | ".join(f"{b} ep" for b in CHECKPOINTS)
    lines = [f"Regenerate: `python benchmarks/search_methods.py` ({wall / 60:.0f} min here, 2 workers).", "",
             f"| policy | method | {head} |", "|---|---|" + "---|" * len(CHECKPOINTS)]
    for policy, r in results.items():
        lines.append(f"| {policy} | base (Gaussian) |" + f" {r['base']:.0%} |" * len(CHECKPOINTS))
        for m in METHODS:
            lines.append(f"| {policy} | {m} | " + " | ".join(f"{p['heldout']:.0%} ({p['search']:.0%})"
                                                           for p in r[m]) + " |")
    base = np.mean([r["base"] for r in results.values()])
    lines += ["", f"Held-out success of the best-so-far ticket on {HELDOUT} held-out seeds (in brackets: its "
              f"success on the search seeds it ran, all {SEARCH_SEEDS} once any ticket has), one search per "
              "method and policy.",
              f"Best mean over the {len(results)} policies (base: {base:.1%}), per budget: "
              + ", ".join(f"{b} ep: **{m}** {v:.1%}"
                          for b, (m, v) in zip(CHECKPOINTS, winners(results), strict=True)),
              f"Regression to the mean: a chosen ticket's search success exceeds its held-out success by "
              f"{100 * shrinkage(results):.1f} points on average."]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.6 * len(results), 8))
    axes = fig.subplots(2, len(results), squeeze=False)
    styles = ("-o", "--s", "-^", "-D", "-P", ":v", "-.x")
    for column, (policy, r) in enumerate(results.items()):
        curves, scatter = axes[0][column], axes[1][column]
        for m, style in zip(METHODS, styles, strict=True):  # RS and CEM may coincide
            curves.plot(CHECKPOINTS, [p["heldout"] for p in r[m]], style, label=m)
            scatter.scatter([p["search"] for p in r[m]], [p["heldout"] for p in r[m]], s=14, label=m)
        for ax in (curves, scatter):
            ax.axhline(r["base"], color="grey", linestyle="--", label="base (Gaussian)")
        curves.set(xscale="log", xticks=CHECKPOINTS, xticklabels=[str(b) for b in CHECKPOINTS],
                   title=policy.removeprefix("metaworld/"), xlabel="search episodes", ylim=(0, 1))
        curves.minorticks_off()
        scatter.plot([0, 1], [0, 1], color="0.7", linewidth=1)
        scatter.set(xlim=(0, 1.02), ylim=(0, 1.02), xlabel=f"search success ({SEARCH_SEEDS} seeds)",
                    title="regression to the mean")
    axes[0][0].set_ylabel(f"held-out success ({HELDOUT} seeds)")
    axes[1][0].set_ylabel(f"held-out success ({HELDOUT} seeds)")
    axes[0][0].legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=HERE / "runs" / "search_methods")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    args.runs.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    results = {p: compare(p, args.runs, args.workers) for p in POLICIES}
    wall = time.perf_counter() - start
    settings = {"methods": METHODS, "checkpoints": CHECKPOINTS, "search_seeds": SEARCH_SEEDS,
                "heldout": HELDOUT}
    write_results("search_methods", {"settings": settings, "results": results, "wall_seconds": wall},
                  markdown(results, wall), lambda path: plot(results, path))


if __name__ == "__main__":
    main()

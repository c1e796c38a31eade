"""Search-method comparison: held-out success of the best-so-far ticket against episodes spent.

    python benchmarks/search_methods.py       # writes benchmarks/results/search_methods.{md,json,png}

RS, CEM, ZOS, CEM+racing and CMA-ES on two bundled policies, three search seeds each (20 tickets
per RS batch, CEM or CMA-ES generation, 10 ZOS candidates per step). At each checkpoint budget the search is
replayed from its seed with that budget (recorded episodes are read back, not re-run), and its
best ticket (by search score) is rolled out on held-out seeds. Resumable: all episodes of one
policy share a run store under `--runs`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from goldenticket.evaluation import Evaluator
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import MLPPolicy, load_policy
from goldenticket.rollout import Engine
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in
from goldenticket.ticket_search import make_optimizer, run_search
from goldenticket.tickets import Ticket
from goldenticket.workflow import query_evaluator

HERE = Path(__file__).parent
POLICIES = ("metaworld/reach-v3/ddim@8", "metaworld/pick-place-v3/flow")
METHODS = {"rs": {"batch_size": 20}, "cem": {"population": 20}, "zos": {"candidates": 10},
           "cem-racing": {"population": 20}, "cma-es": {"population": 20}}
SEEDS = (0, 1, 2)
CHECKPOINTS = (50, 100, 200, 400, 1000)  # search episodes
SEARCH_SEEDS, HELDOUT = 10, 100


def best_at(evaluator: Evaluator, policy: MLPPolicy, method: str, seed: int, budget: int) -> Ticket:
    """The best ticket a search with this budget ends with (replayed from its seed)."""
    optimizer = make_optimizer(method, policy.noise_shape, seeds_in("search", SEARCH_SEEDS),
                               np.random.default_rng(seed), **METHODS[method])
    fingerprint = policy.fingerprint()
    result = run_search(optimizer, query_evaluator(evaluator, fingerprint), budget=budget)
    top = result.top(1, min_episodes=SEARCH_SEEDS) or result.top(1)
    return Ticket(top[0].ticket, {"policy_fingerprint": fingerprint})


def held_out(evaluator: Evaluator, ticket: Ticket | None) -> float:
    label, source = ("base", Gaussian(0)) if ticket is None else (ticket.id, Constant(ticket.noise))
    results = evaluator.run([(label, source, seeds_in("heldout", HELDOUT))])[0]
    return float(np.mean([r.success for r in results]))


def compare(policy: str, runs: Path, workers: int) -> dict:
    """{"base": rate, method: [[rate per checkpoint] per seed]} for one policy."""
    task, loaded = get_task(policy.rsplit("/", 1)[0]), load_policy(policy)
    runs.mkdir(parents=True, exist_ok=True)
    out = {}
    with Engine(policy, task, workers=workers) as engine, \
            RunStore(runs / f"{policy.replace('/', '_')}.sqlite") as store:
        evaluator = Evaluator(engine, store)
        out["base"] = held_out(evaluator, None)
        for method in METHODS:
            out[method] = [[held_out(evaluator, best_at(evaluator, loaded, method, s, b))
                            for b in CHECKPOINTS] for s in SEEDS]
            print(f"{policy} {method}: mean held-out {np.mean(out[method], axis=0).round(3).tolist()}",
                  flush=True)
    return out


def winners(results: dict) -> list[tuple[str, float]]:
    """Per checkpoint, the method with the highest mean held-out success over policies and seeds,
    with that mean."""
    means = {m: np.mean([np.mean(r[m], axis=0) for r in results.values()], axis=0) for m in METHODS}
    best = [max(METHODS, key=lambda m: means[m][i]) for i in range(len(CHECKPOINTS))]
    return [(m, float(means[m][i])) for i, m in enumerate(best)]


def markdown(results: dict) -> str:
    head = " | ".join(f"{b} ep" for b in CHECKPOINTS)
    lines = [f"| policy | method | {head} |", "|---|---|" + "---|" * len(CHECKPOINTS)]
    for policy, r in results.items():
        lines.append(f"| {policy} | base (Gaussian) |" + f" {r['base']:.0%} |" * len(CHECKPOINTS))
        for m in METHODS:
            mean, low, high = np.mean(r[m], 0), np.min(r[m], 0), np.max(r[m], 0)
            cells = [f"{a:.0%} ({lo:.0%}-{hi:.0%})" for a, lo, hi in zip(mean, low, high, strict=True)]
            lines.append(f"| {policy} | {m} | " + " | ".join(cells) + " |")
    lines += ["", f"Mean over {len(SEEDS)} search seeds (min-max) of the best-so-far ticket's success on "
              f"{HELDOUT} held-out seeds; search on {SEARCH_SEEDS} search seeds.",
              f"Best mean over both policies (base: {np.mean([r['base'] for r in results.values()]):.1%}), "
              "per budget: " + ", ".join(f"{b} ep: **{m}** {v:.1%}"
                                         for b, (m, v) in zip(CHECKPOINTS, winners(results), strict=True))]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5.5 * len(results), 4), sharey=True)
    for ax, (policy, r) in zip(np.atleast_1d(axes), results.items(), strict=True):
        for m, style in zip(METHODS, ("-o", "--s", "-^", "-D", ":v"), strict=True):  # RS and CEM may coincide
            runs = np.array(r[m])
            ax.plot(CHECKPOINTS, runs.mean(0), style, label=m)
            ax.fill_between(CHECKPOINTS, runs.min(0), runs.max(0), alpha=0.15)
        ax.axhline(r["base"], color="grey", linestyle="--", label="base (Gaussian)")
        ax.set(xscale="log", xticks=CHECKPOINTS, xticklabels=[str(b) for b in CHECKPOINTS],
               title=policy, xlabel="search episodes")
        ax.minorticks_off()
    np.atleast_1d(axes)[0].set_ylabel(f"held-out success ({HELDOUT} seeds)")
    np.atleast_1d(axes)[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=HERE / "runs" / "search_methods")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    results = {p: compare(p, args.runs, args.workers) for p in POLICIES}
    out = HERE / "results"
    out.mkdir(exist_ok=True)
    settings = {"methods": METHODS, "seeds": SEEDS, "checkpoints": CHECKPOINTS,
                "search_seeds": SEARCH_SEEDS, "heldout": HELDOUT}
    (out / "search_methods.json").write_text(json.dumps({"settings": settings, "results": results},
                                                        indent=2) + "\n")
    (out / "search_methods.md").write_text(markdown(results))
    plot(results, out / "search_methods.png")
    print(markdown(results))


if __name__ == "__main__":
    main()

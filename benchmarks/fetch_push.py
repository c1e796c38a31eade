"""The second environment family at real budgets: golden tickets for the example DDIM policy
(diffusers adapter) on FetchPush-v4 (gymnasium-robotics), through the Python API.

    python benchmarks/fetch_push.py          # writes benchmarks/results/fetch_push.{md,json}
    python benchmarks/fetch_push.py --curve  # the budget curve's searches: fetch_push_curve.{md,json}

Searches with each of METHODS (the default search first, then CEM+racing, which found the ticket
shipped in examples/) on the search seeds and judges the top tickets on 200 held-out seeds, then
runs the best ticket, the base and the zero ticket again on 300 fresh held-out seeds that no
search or selection saw. Resumable: each method's run store lives in `--runs`/<method>.
`--curve` runs, instead, the searches that the budget curve compares on Meta-World, with the
`search` defaults otherwise (20 search seeds, 40 validation seeds): FetchPush as a task nobody
tuned them for.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from results_files import write_results

import goldenticket
from goldenticket.config import SearchConfig
from goldenticket.evaluation import to_dicts
from goldenticket.report import p_vs_base, rate_text

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent))  # the repository root: tickets name the task as the CLI does
from examples import fetch_push  # noqa: E402

FRESH = range(1_005_000, 1_005_300)
METHODS = (SearchConfig("", "").method, "cem-racing")
CURVE = {"cma-es, tiled, 850": {"budget": 850},  # searches the budget curve compares
         "cma-es, tiled, 300, 20 validation seeds": {"budget": 300, "validation_seeds": 20},
         "tiled-then-full, full, 1600": {"budget": 1600, "method": "tiled-then-full", "subspace": "full"}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/fetch-push"))
    parser.add_argument("--budget", type=int, default=8000)
    parser.add_argument("--search-seeds", type=int, default=100)
    parser.add_argument("--validation-seeds", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--curve", action="store_true", help="the budget curve's searches instead")
    args = parser.parse_args()
    if args.curve:
        results = {name: run(args.runs / "curve" / name.replace(", ", "_"), changed, args.workers)
                   for name, changed in CURVE.items()}
        said = "The `search` defaults where a search names nothing else (20 search, 40 validation seeds)"
        write_results("fetch_push_curve", results, report(results, f"{said}, {args.workers} workers."))
        return
    searches = {method: {"method": method, "budget": args.budget, "search_seeds": args.search_seeds,
                         "validation_seeds": args.validation_seeds} for method in METHODS}
    results = {method: run(args.runs / method, options, args.workers) for method, options in searches.items()}
    write_results("fetch_push", results, report(results, f"{args.search_seeds} search seeds, "
                  f"{args.validation_seeds} validation seeds, {args.workers} workers."))


def run(out: Path, options: dict, workers: int) -> dict:
    """One search with `options` into `out` and its best ticket's fresh check, timed."""
    start, policy = time.perf_counter(), fetch_push.make_policy()
    summary = goldenticket.search(policy, fetch_push.make_env, out, workers=workers, **options)
    searched = time.perf_counter()
    fresh = goldenticket.evaluate(policy, fetch_push.make_env, [summary.best.path], FRESH,
                                  workers=workers)
    done = time.perf_counter()
    recorded = summary.to_dict()
    keys = ("base", "zero", "best", "deliver", "search_episodes", "heldout_seeds")
    return {"search": {k: recorded[k] for k in keys},
            "fresh": to_dicts(fresh), "fresh_seeds": [FRESH.start, FRESH.stop - 1],
            "options": options | {"runs": str(out), "workers": workers},
            "wall_seconds": {"search": round(searched - start), "fresh": round(done - searched)}}


def report(results: dict, footer: str) -> str:
    lines = ["| search | held-out seeds | base | zero ticket | best ticket | p vs base | p vs zero |",
             "|---|---|---|---|---|---|---|"]
    for method, r in results.items():
        best_id, wall = r["search"]["best"]["ticket_id"], r["wall_seconds"]
        search = (f"{method}, {r['search']['search_episodes']} episodes: ticket {best_id}, delivers the "
                  f"{r['search']['deliver']} ({wall['search']} s search and verdict, {wall['fresh']} s fresh "
                  "check)")
        for label, rows, seeds in (("judged (top tickets)", r["search"] | {best_id: r["search"]["best"]},
                                    r["search"]["heldout_seeds"]),
                                   ("fresh (best ticket)", r["fresh"], r["fresh_seeds"])):
            best = rows[best_id]
            rates = " | ".join(rate_text(r) for r in (rows["base"], rows["zero"], best))
            lines.append(f"| {search} | {label}: {seeds[0]}:{seeds[1] + 1} | {rates} | "
                         f"{p_vs_base(best):.2g} | {best['p_vs_zero']:.2g} |")
            search = ""
    return "\n".join(lines) + f"\n\n{footer}\n"


if __name__ == "__main__":
    main()

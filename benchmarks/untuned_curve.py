"""The budget curve's searches on tasks nobody tuned them for: the FetchPush example's DDIM policy
(diffusers adapter, gymnasium-robotics) and the bundled image policy (Meta-World drawer-open seen
through a camera).

    python benchmarks/untuned_curve.py fetch-push  # benchmarks/results/fetch_push_curve.{md,json}
    python benchmarks/untuned_curve.py pixels      # benchmarks/results/pixels_curve.{md,json}

Runs the searches that the budget curve compares on Meta-World (CURVE), with the `search`
defaults otherwise (20 search seeds, 40 validation seeds), each into its own resumable run folder
under --runs, and judges each one's best ticket again, with the base and the zero ticket, on the
same 300 fresh held-out seeds that no search or selection saw.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from results_files import write_results

import goldenticket
from goldenticket.report import p_vs_base, rate_text

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent))  # the repository root: tickets name the task as the CLI does
from examples import fetch_push  # noqa: E402

FRESH = range(1_005_000, 1_005_300)
TILED = {"method": "cma-es", "subspace": "tiled"}  # CMA-ES over a tiled ticket
CURVE = {"cma-es, tiled, 850": TILED | {"budget": 850, "halving": False},  # the budget curve's searches
         "cma-es, tiled, 300, 20 validation seeds": TILED | {"budget": 300, "validation_seeds": 20,
                                                             "halving": False},
         "tiled-then-full, full, 1600": {"budget": 1600, "method": "tiled-then-full", "subspace": "full",
                                         "halving": False},
         "cma-es, tiled, 1100, halved": TILED | {"budget": 1100, "halving": True},
         "cma-es, tiled, 350, halved": TILED | {"budget": 350, "halving": True}}
TARGETS = {"fetch-push": ("fetch_push_curve", lambda: (fetch_push.make_policy(), fetch_push.make_env)),
           "pixels": ("pixels_curve", lambda: ("metaworld-pixels/drawer-open-v3/flow",
                                               "metaworld-pixels/drawer-open-v3"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("target", choices=list(TARGETS), help="the policy and task")
    parser.add_argument("--runs", type=Path, default=None, help="run folders (default: runs/<target>/curve)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    name, make = TARGETS[args.target]
    runs = args.runs or Path("runs") / args.target / "curve"
    policy, task = make()
    results = {search: run(policy, task, runs / search.replace(", ", "_"), changed, args.workers)
               for search, changed in CURVE.items()}
    said = ("Halved where a search says so, else every ticket on every seed; the `search` defaults where a "
            "search names nothing else (20 search, 40 validation seeds)")
    write_results(name, results, report(results, f"{said}, {args.workers} workers."))


def run(policy, task, out: Path, options: dict, workers: int) -> dict:
    """One search of `policy` on `task` with `options` into `out`, and its best ticket's fresh
    check, timed."""
    start = time.perf_counter()
    summary = goldenticket.search(policy, task, out, workers=workers, **options)
    searched = time.perf_counter()
    fresh = goldenticket.evaluate(policy, task, [summary.best.path], FRESH, workers=workers)
    done = time.perf_counter()
    recorded = summary.to_dict()
    keys = ("base", "zero", "best", "deliver", "search_episodes", "heldout_seeds")
    return {"search": {k: recorded[k] for k in keys},
            "fresh": {arm: row.to_dict() for arm, row in fresh.items()},
            "fresh_seeds": [FRESH.start, FRESH.stop - 1],
            "options": options | {"runs": str(out), "workers": workers},
            "wall_seconds": {"search": round(searched - start), "fresh": round(done - searched)}}


def report(results: dict, footer: str) -> str:
    """Per search: base, zero ticket and best ticket on the judged seeds and the fresh ones."""
    lines = ["| search | held-out seeds | base | zero ticket | best ticket | p vs base | p vs zero |",
             "|---|---|---|---|---|---|---|"]
    for method, r in results.items():
        best_id, wall = r["search"]["best"]["ticket_id"], r["wall_seconds"]
        search = (f"{method}, {r['search']['search_episodes']} episodes: ticket {best_id}, delivers the "
                  f"{r['search']['deliver']} "
                  f"({wall['search']} s search and verdict, {wall['fresh']} s fresh check)")
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

"""The second environment family at real budgets: golden tickets for the example DDIM policy
(diffusers adapter) on FetchPush-v4 (gymnasium-robotics), through the Python API.

    python benchmarks/fetch_push.py  # writes benchmarks/results/fetch_push.{md,json}

Searches with each of METHODS (CMA-ES, every ticket on every seed, then CEM+racing, which found the ticket
shipped in examples/) on the search seeds and judges the top tickets on 200 held-out seeds, then
runs the best ticket, the base and the zero ticket again on 300 fresh held-out seeds that no
search or selection saw. Resumable: each method's run store lives in `--runs`/<method>. The
budget curve's searches on this task: `untuned_curve.py fetch-push`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from results_files import write_results
from untuned_curve import TARGETS, report, run

METHODS = ("cma-es", "cem-racing")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/fetch-push"))
    parser.add_argument("--budget", type=int, default=8000)
    parser.add_argument("--search-seeds", type=int, default=100)
    parser.add_argument("--validation-seeds", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    searches = {method: {"method": method, "budget": args.budget, "search_seeds": args.search_seeds,
                         "validation_seeds": args.validation_seeds, "halving": False} for method in METHODS}
    policy, task = TARGETS["fetch-push"][1]()
    results = {method: run(policy, task, args.runs / method, options, args.workers)
               for method, options in searches.items()}
    write_results("fetch_push", results, report(results, f"{args.search_seeds} search seeds, "
                  f"{args.validation_seeds} validation seeds, {args.workers} workers."))


if __name__ == "__main__":
    main()

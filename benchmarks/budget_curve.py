"""The budget curve: what more search episodes buy on the pairs with a weak base.

    python benchmarks/budget_curve.py [--budgets 2000 ...]     # resumable, pair by pair
    python benchmarks/budget_curve.py --plot-only              # redraw budget_curve.png

At each search budget, every pair whose base succeeds at most 85% in the existence table is
searched and judged as `existence.py` does it (the `search` defaults but the budget), and its best
ticket judged again, with base and zero ticket, on the same two fresh ranges. The point at the
default budget is the existence table's own. Each pair's row is kept in
benchmarks/results/budget_curve/<budget>/ once judged, so a run resumes pair by pair, on another
machine too; its run folder under benchmarks/runs/budget-<budget>/ resumes a pair's episodes.
Results, for the budgets that have every pair: benchmarks/results/budget_curve.{md,json,png}.
"""

from __future__ import annotations

import argparse
import json
import time

from existence import FRESH_RANGES, HERE, SETTINGS, WEAK_BASE, run_folder, run_pair, table_row, target_summary
from results_files import RESULTS, write_results

from goldenticket.files import write_atomic

ROWS = RESULTS / "budget_curve"
RANGES = {"fresh": "fresh seeds", "fresh_2": "second fresh range"}
TARGETS = {"vs_base": 0.9, "failure_reduction": 0.55, "mean_gain": 0.18}
TITLES = {"vs_base": "pairs significantly above the base", "failure_reduction": "mean failure reduction",
          "mean_gain": "mean gain in success rate"}


def existence_rows() -> list[dict]:
    return json.loads((RESULTS / "existence.json").read_text())["pairs"]


def weak_rows() -> list[dict]:
    """The existence table's rows of the pairs with a weak base, in its order."""
    return [r for r in existence_rows() if r["base"]["success_rate"] <= WEAK_BASE]


def weak_pairs() -> list[tuple[str, str]]:
    """(task, policy) of the existence table's pairs with a weak base, in its order."""
    return [(f"metaworld/{r['task']}", f"metaworld/{r['task']}/{r['policy']}") for r in weak_rows()]


def budget_rows(budget: int, workers: int) -> list[dict]:
    """Every weak pair's row at `budget`: read back where kept, else searched, judged and kept."""
    rows, todo = [], weak_pairs()
    for i, (task, policy) in enumerate(todo, 1):
        path = run_folder(ROWS / str(budget), policy).with_suffix(".json")
        if not path.exists():
            print(f"[budget {budget}, {i}/{len(todo)}] {policy}", flush=True)
            start = time.perf_counter()
            row = table_row(run_pair(task, policy, HERE / "runs" / f"budget-{budget}", workers, budget))
            write_atomic(path, json.dumps(row | {"wall_time_s": round(time.perf_counter() - start)},
                                          indent=2) + "\n")
        rows.append(json.loads(path.read_text()))
    return rows


def kept_budgets() -> list[int]:
    """The budgets whose every weak pair has a kept row, with the default's."""
    pairs, folders = len(weak_pairs()), ROWS.iterdir() if ROWS.exists() else []
    full = [int(d.name) for d in folders if len(list(d.glob("*.json"))) == pairs]
    return sorted({SETTINGS["budget"], *full})


def curve() -> list[dict]:
    """Per budget: its targets and episodes (the default budget's from the existence table)."""
    points = []
    for budget in kept_budgets():
        rows = weak_rows() if budget == SETTINGS["budget"] else [
            json.loads(p.read_text()) for p in sorted((ROWS / str(budget)).glob("*.json"))]
        points.append({"budget": budget} | target_summary(rows))
    return points


def markdown(points: list[dict]) -> str:
    lines = [f"Regenerate: `python benchmarks/budget_curve.py --budgets "
             f"{' '.join(str(p['budget']) for p in points if p['budget'] != SETTINGS['budget'])}` "
             f"(the {SETTINGS['budget']}-episode point is the existence table).", "",
             "| search budget | search + validation episodes, mean (max) | seeds | significant vs base "
             "| vs zero | mean failure reduction | mean gain | below zero | below base |",
             "|---|---|---|---|---|---|---|---|---|"]
    for p in points:
        for key, said in RANGES.items():
            t = p["targets"][key]
            lines.append(f"| {p['budget']} | {p['episodes']['mean']:.0f} ({p['episodes']['max']}) | {said} | "
                         f"{t['vs_base']:.0%} | {t['vs_zero']:.0%} | {t['failure_reduction']:.1%} | "
                         f"{100 * t['mean_gain']:+.1f} | {t['below_zero']} | {t['below_base']} |")
    lines.append("| target | <= 1250 | both | >= 90% | | >= 55% | >= +18 | 0 | 0 |")
    lines += ["", f"Over the {points[0]['targets']['pairs']} pairs whose base succeeds at most "
              f"{WEAK_BASE:.0%}; settings otherwise the `search` defaults ({SETTINGS['method']}, "
              f"{SETTINGS['validation_seeds']} validation seeds, top {SETTINGS['top_k']} judged on "
              f"{SETTINGS['heldout']} held-out seeds, the zero ticket beside them); each pair's best ticket "
              "judged again on two ranges of 200 fresh held-out seeds. Significance: one-sided exact paired "
              "test, p < 0.05."]
    return "\n".join(lines) + "\n"


def plot(points: list[dict], path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 3.8))
    for ax, (metric, target) in zip(fig.subplots(1, len(TARGETS)), TARGETS.items(), strict=True):
        for key, said in RANGES.items():
            ax.plot([p["episodes"]["mean"] for p in points], [p["targets"][key][metric] for p in points],
                    "-o", label=said)
        ax.axhline(target, color="tab:red", ls="--", label=f"target {target:.0%}")
        ax.axvline(1250, color="0.6", ls=":", label="1250 episodes")
        ax.set(xlabel="search + validation episodes per pair (mean)", title=TITLES[metric])
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budgets", nargs="+", type=int, default=[2000], help="search budgets to add")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--plot-only", action="store_true", help="redraw budget_curve.png; run no episode")
    args = parser.parse_args()
    if min(args.budgets) < 1 or args.workers < 1:
        parser.error("--budgets and --workers must be >= 1")
    if not args.plot_only:
        for budget in args.budgets:
            if budget != SETTINGS["budget"]:
                budget_rows(budget, args.workers)
    points = curve()
    record = {"settings": SETTINGS | {"weak_base": WEAK_BASE, "fresh_ranges": FRESH_RANGES}, "points": points}
    if args.plot_only:
        plot(points, RESULTS / "budget_curve.png")
        return
    write_results("budget_curve", record, markdown(points), lambda path: plot(points, path))


if __name__ == "__main__":
    main()

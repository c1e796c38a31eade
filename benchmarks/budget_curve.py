"""The budget curve: what more search episodes buy on the pairs with a weak base.

    python benchmarks/budget_curve.py [--budgets 2000 ...]     # resumable, pair by pair
    python benchmarks/budget_curve.py --budgets 850 --subspace full [--search-seeds 40]
    python benchmarks/budget_curve.py --budgets 850 --method gp            # another method
    python benchmarks/budget_curve.py --budgets 300 --validation-seeds 20  # 500 episodes in all
    python benchmarks/budget_curve.py --budgets 850 --halving  # search and validation halved
    python benchmarks/budget_curve.py --plot-only              # redraw budget_curve.png

At each search budget, every pair whose base succeeds at most 85% in the existence table is
searched and judged as `existence.py` does it, by CMA-ES over a tiled ticket, every ticket on every
search seed (the default search before the portfolio; the `search` defaults otherwise), and its best
ticket judged again, with base and zero ticket, on the same two fresh ranges. `--search-seeds`,
`--subspace`, `--method`, `--race`, `--halving`, `--validation-seeds`, `--seed` (another draw of
the same search), `--population`, `--full-population` and `--full-start` (the portfolio's full
search's tickets a generation and start) change the search at those budgets (a point is a budget
and a search). The point at the default budget and search (`--budgets 1100 --method portfolio
--subspace full --halving`) is the existence table's own. Each
pair's row is kept in benchmarks/results/budget_curve/<point>/ once judged (<point>: the budget,
then -seedsN, -valN, -raceP, -seedN, -popN, -fullpopN, -halving, -full, the method, its dashes
written as underscores, and -start_S, where they differ from CMA-ES tiled's), so a run resumes pair
by pair, on another machine too; its run folder under benchmarks/runs/budget-<point>/ resumes a
pair's episodes.
Results, for the budgets that have every pair: benchmarks/results/budget_curve.{md,json,png}.
"""

from __future__ import annotations

import argparse
import json

from existence import FRESH_RANGES, HERE, SETTINGS, WEAK_BASE, run_folder, run_pair, table_row, target_summary
from results_files import RESULTS, write_results

from goldenticket.files import write_atomic
from goldenticket.ticket_search import METHODS
from goldenticket.ticket_search.methods import FULL_STARTS

ROWS = RESULTS / "budget_curve"
SEARCH = {"search_seeds": SETTINGS["search_seeds"], "subspace": "tiled", "method": "cma-es",
          "validation_seeds": SETTINGS["validation_seeds"], "seed": SETTINGS["seed"], "race": None,
          "population": None, "full_population": None, "full_start": None,
          "halving": False}  # what a point may change (None: the method's), from CMA-ES over a tiled ticket
# the existence table's point: the `search` defaults
DEFAULT = (SETTINGS["budget"], SEARCH | {k: SETTINGS[k] for k in ("method", "subspace", "halving")})
METHOD_SETTINGS = ("population", "full_population", "full_start")  # a point's changes: its method's settings
FROM = {"zero": "w = 0", "tiled": "the tiled search's best"}  # the portfolio's full_start, said
RANGES = {"fresh": "fresh seeds", "fresh_2": "second fresh range"}
TARGETS = {"vs_base": 0.9, "failure_reduction": 0.55, "mean_gain": 0.18}
TITLES = {"vs_base": "pairs significantly above the base", "failure_reduction": "mean failure reduction",
          "mean_gain": "mean gain in success rate"}
TOKENS = {"search_seeds": "seeds", "validation_seeds": "val", "race": "race", "seed": "seed",
          "population": "pop", "full_population": "fullpop"}  # a folder's numeric parts


def existence_rows() -> list[dict]:
    return json.loads((RESULTS / "existence.json").read_text())["pairs"]


def weak_rows() -> list[dict]:
    """The existence table's rows of the pairs with a weak base, in its order."""
    return [r for r in existence_rows() if r["base"]["success_rate"] <= WEAK_BASE]


def weak_pairs() -> list[tuple[str, str]]:
    """(task, policy) of the existence table's pairs with a weak base, in its order."""
    return [(f"metaworld/{r['task']}", f"metaworld/{r['task']}/{r['policy']}") for r in weak_rows()]


def folder_name(budget: int, search: dict) -> str:
    """Where a point's rows are kept: its budget, then what it changes of the default search
    (a method's dashes written as underscores)."""
    changed = [f"{TOKENS[k]}{search[k]}" for k in TOKENS if search[k] != SEARCH[k]]
    if search["halving"]:
        changed.append("halving")
    if search["subspace"] != SEARCH["subspace"]:
        changed.append(search["subspace"])
    if search["method"] != SEARCH["method"]:
        changed.append(search["method"].replace("-", "_"))
    if search["full_start"] is not None:
        changed.append(f"start_{search['full_start']}")
    return "-".join([str(budget), *changed])


def point_of(name: str) -> tuple[int, dict]:
    """The budget and search of a folder named by `folder_name`."""
    budget, *changed = name.split("-")
    search = dict(SEARCH)
    for part in changed:
        key = next((k for k, token in TOKENS.items() if part.startswith(token)
                    and part[len(token):][:1].isdigit()), None)
        if key:
            number = part.removeprefix(TOKENS[key])
            search[key] = float(number) if key == "race" else int(number)
        elif part == "halving":
            search["halving"] = True
        elif part in ("full", "tiled"):
            search["subspace"] = part
        elif part.startswith("start_"):
            search["full_start"] = part.removeprefix("start_")
        else:
            search["method"] = part.replace("_", "-")
    return int(budget), search


def search_of(point: dict) -> dict:
    """What a point's search changes: its entries of SEARCH."""
    return {k: point[k] for k in SEARCH}


def search_label(search: dict) -> str:
    said = [f"{search['search_seeds']} seeds",
            "" if search["subspace"] == SEARCH["subspace"] else search["subspace"],
            "" if search["method"] == SEARCH["method"] else search["method"],
            "" if search["race"] is None else f"raced at {search['race']}",
            "" if search["validation_seeds"] == SEARCH["validation_seeds"] else
            f"{search['validation_seeds']} validation seeds",
            "" if search["seed"] == SEARCH["seed"] else f"seed {search['seed']}",
            "" if search["population"] is None else f"{search['population']} tickets a generation",
            "" if search["full_population"] is None else
            f"{search['full_population']} a generation of the full search",
            "" if search["full_start"] is None else f"the full search from {FROM[search['full_start']]}",
            "halved" if search["halving"] else ""]
    return ", ".join(filter(None, said))


def settings_of(search: dict) -> dict:
    """The search settings of a point's search: the populations and a full search's start are the
    method's settings."""
    own = {k: search[k] for k in METHOD_SETTINGS if search[k] is not None}
    return {k: v for k, v in search.items() if k not in METHOD_SETTINGS} | ({"optimizer": own} if own else {})


def budget_rows(budget: int, search: dict, workers: int) -> list[dict]:
    """Every weak pair's row at `budget` with `search`: read back where kept, else searched, judged
    and kept."""
    rows, todo, name = [], weak_pairs(), folder_name(budget, search)
    for i, (task, policy) in enumerate(todo, 1):
        path = run_folder(ROWS / name, policy).with_suffix(".json")
        if not path.exists():
            print(f"[budget {budget}, {search_label(search)}, {i}/{len(todo)}] {policy}", flush=True)
            summary = run_pair(task, policy, HERE / "runs" / f"budget-{name}", workers, budget=budget,
                               **settings_of(search))
            write_atomic(path, json.dumps(table_row(summary), indent=2) + "\n")
        rows.append(json.loads(path.read_text()))
    return rows


def kept_points() -> list[tuple[int, dict]]:
    """(budget, search) of every point whose weak pairs all have a kept row, with the default's;
    the default search first, then by search and budget."""
    pairs, folders = len(weak_pairs()), ROWS.iterdir() if ROWS.exists() else []
    full = [point_of(d.name) for d in folders if len(list(d.glob("*.json"))) == pairs]
    points = {folder_name(b, s): (b, s) for b, s in [DEFAULT, *full]}
    return sorted(points.values(), key=lambda p: (p[1] != DEFAULT[1], search_label(p[1]), p[0]))


def curve() -> list[dict]:
    """Per point: its targets and episodes (the default's from the existence table)."""
    points = []
    for budget, search in kept_points():
        rows = weak_rows() if (budget, search) == DEFAULT else [
            json.loads(p.read_text()) for p in sorted((ROWS / folder_name(budget, search)).glob("*.json"))]
        points.append({"budget": budget} | search | target_summary(rows))
    return points


def searches(points: list[dict]) -> list[dict]:
    """The distinct searches of `points`, in their order."""
    return list({search_label(p): search_of(p) for p in points}.values())


def command(search: dict, points: list[dict]) -> str:
    """The command that makes `search`'s points but the existence table's ("" where none is left)."""
    budgets = [p["budget"] for p in points if search_of(p) == search
               and (p["budget"], search) != DEFAULT]
    if not budgets:
        return ""
    flags = "".join(f" --{k.replace('_', '-')}" + ("" if search[k] is True else f" {search[k]}")
                    for k in SEARCH if search[k] != SEARCH[k])
    return f"`python benchmarks/budget_curve.py --budgets {' '.join(map(str, budgets))}{flags}`"


def markdown(points: list[dict]) -> str:
    lines = ["Regenerate: " + ", ".join(filter(None, (command(s, points) for s in searches(points)))) +
             f" (the {DEFAULT[0]}-episode point with {search_label(DEFAULT[1])} is the existence "
             "table).", "",
             "| search budget | search | search + validation episodes, mean (max) | seeds | significant "
             "vs base | vs zero | mean failure reduction | mean gain | below zero | below base |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for p in points:
        for key, said in RANGES.items():
            t = p["targets"][key]
            lines.append(f"| {p['budget']} | {search_label(p)} | {p['episodes']['mean']:.0f} "
                         f"({p['episodes']['max']}) | {said} | {t['vs_base']:.0%} | {t['vs_zero']:.0%} | "
                         f"{t['failure_reduction']:.1%} | {100 * t['mean_gain']:+.1f} | {t['below_zero']} | "
                         f"{t['below_base']} |")
    lines.append("| target | | <= 1250 | both | >= 90% | | >= 55% | >= +18 | 0 | 0 |")
    lines += ["", "What the job delivers: the best ticket, or the base where the best ticket did not succeed "
              "more often than the base on the judged held-out seeds (it then says to keep the base; the "
              "zero ticket is among the judged tickets, so it is delivered where it is the best), on the "
              "same fresh ranges:", "",
              "| search budget | search | pairs that keep the base | seeds | significant vs base | mean "
              "failure reduction | mean gain |", "|---|---|---|---|---|---|---|"]
    for p in points:
        for key, said in RANGES.items():
            d = p["targets"][key]["delivered"]
            lines.append(f"| {p['budget']} | {search_label(p)} | {d['kept_base']} | {said} | "
                         f"{d['vs_base']:.0%} | {d['failure_reduction']:.1%} | {100 * d['mean_gain']:+.1f} |")
    lines += ["", f"Over the {points[0]['targets']['pairs']} pairs whose base succeeds at most "
              f"{WEAK_BASE:.0%}; settings otherwise the `search` defaults ("
              f"{SETTINGS['validation_seeds']} validation seeds, top {SETTINGS['top_k']} judged on "
              f"{SETTINGS['heldout']} held-out seeds, the zero ticket beside them); search: the search "
              "seeds, the sub-space searched (full: every entry of the ticket; tiled: one action-sized "
              "vector repeated over the horizon), the method where it is not CMA-ES, the racing level "
              "where tickets are raced (search `--race`), halved where search and validation are raced by "
              "sequential halving (search `--halving`), the validation seeds where they are not "
              f"{SEARCH['validation_seeds']} and CMA-ES's tickets a generation where they are not 20; "
              "each pair's best ticket judged again on two ranges of 200 "
              "fresh held-out seeds. Significance: one-sided exact paired test, p < 0.05."]
    return "\n".join(lines) + "\n"


def plot(points: list[dict], path) -> None:
    """Each target's metric, the mean of the two fresh ranges, against the episodes spent: one line
    per search."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter, PercentFormatter, ScalarFormatter

    fig = Figure(figsize=(13, 5.4))
    for ax, (metric, target) in zip(fig.subplots(1, len(TARGETS)), TARGETS.items(), strict=True):
        for i, search in enumerate(searches(points)):
            mine = [p for p in points if search_of(p) == search]
            ax.plot([p["episodes"]["mean"] for p in mine],
                    [sum(p["targets"][key][metric] for key in RANGES) / len(RANGES) for p in mine],
                    "-o" if i < 10 else "--s", color=f"C{i % 10}", label=search_label(search))
        ax.axhline(target, color="tab:red", ls="--", label="target")
        ax.axvline(1250, color="0.6", ls=":", label="1250 episodes")
        ax.set(xlabel="search + validation episodes per pair (mean, log scale)", xscale="log",
               title=f"{TITLES[metric]} (target {target:.0%})", xticks=[250, 500, 1000, 2000, 4000, 8000])
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.yaxis.set_major_formatter(PercentFormatter(1.0, decimals=0))
    fig.legend(*fig.axes[0].get_legend_handles_labels(), loc="lower center", ncol=4, fontsize="small")
    fig.suptitle("The mean of the two fresh held-out ranges", fontsize="small")
    fig.tight_layout(rect=(0, 0.2, 1, 1))
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budgets", nargs="+", type=int, default=[2000], help="search budgets to add")
    parser.add_argument("--seed", type=int, default=SEARCH["seed"],
                        help="of the search's own draws: another seed, another draw of the same search")
    parser.add_argument("--search-seeds", type=int, default=SEARCH["search_seeds"],
                        help="initial states each ticket is searched on")
    parser.add_argument("--subspace", choices=("full", "tiled"), default=SEARCH["subspace"],
                        help="what the search varies: one action-sized vector repeated over the horizon, "
                        "or every entry")
    parser.add_argument("--method", choices=list(METHODS), default=SEARCH["method"], help="search method")
    parser.add_argument("--race", type=float, default=None, help="race tickets at this level (search --race)")
    parser.add_argument("--validation-seeds", type=int, default=SEARCH["validation_seeds"],
                        help="seeds the search's best tickets are validated on")
    parser.add_argument("--population", type=int, default=None,
                        help="tickets a generation, for the methods that have generations")
    parser.add_argument("--full-population", type=int, default=None,
                        help="tickets a generation of the portfolio's full search (its full_population)")
    parser.add_argument("--full-start", choices=FULL_STARTS, default=None,
                        help="where the portfolio's full search starts (its full_start)")
    parser.add_argument("--halving", action="store_true",
                        help="spend search and validation episodes by sequential halving (search --halving)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--plot-only", action="store_true", help="redraw budget_curve.png; run no episode")
    args = parser.parse_args()
    if min(*args.budgets, args.workers, args.search_seeds, args.validation_seeds, args.population or 1) < 1:
        parser.error("--budgets, --search-seeds, --validation-seeds, --population and --workers must be >= 1")
    if (args.full_population or 2) < 2:
        parser.error("--full-population must be >= 2")
    search = {k: getattr(args, k) for k in SEARCH}
    if not args.plot_only:
        for budget in args.budgets:
            if (budget, search) != DEFAULT:
                budget_rows(budget, search, args.workers)
    points = curve()
    record = {"settings": SETTINGS | {"weak_base": WEAK_BASE, "fresh_ranges": FRESH_RANGES}, "points": points}
    if args.plot_only:
        plot(points, RESULTS / "budget_curve.png")
        return
    write_results("budget_curve", record, markdown(points), lambda path: plot(points, path))


if __name__ == "__main__":
    main()

"""The untuned bench: the search's defaults on policies nobody tuned them for.

    python benchmarks/untuned_bench.py                        # every pair, the default search
    python benchmarks/untuned_bench.py --pairs franka-1003 --search tiled  # CMA-ES over a tiled ticket
    python benchmarks/untuned_bench.py --pairs fetch-push --budgets 250 500 2500  # the budget curve
    lerobot-venv/bin/python benchmarks/untuned_bench.py --pairs smolvla-drawer-open lerobot-reach \
        lerobot-button
    robomimic-venv/bin/python benchmarks/untuned_bench.py --pairs dppo-lift dppo-can

Each pair is searched and judged as the existence table does it (`existence.run_pair`: the `search`
defaults, the best ticket judged again with the base and the zero ticket on two ranges of 200 fresh
held-out seeds that no search or choice saw), under each search named by --search (portfolio: the
defaults; tiled: CMA-ES over a tiled ticket, the default before the portfolio), within each number
of search and validation episodes named by --budgets (the default's 1250, or 250, 500 or 2500: the
search budget 150 below it, search and validation halved). The paper authors' franka_sim checkpoints
1002 and 1003 come from ../shared/franka_sim (their env and checkpoints as module:factory, MIT
licence; needs `pip install dm-robotics-transformations`); their shipped ticket is judged on the
same fresh seeds beside ours. Each pair's row is kept in
benchmarks/results/untuned_bench/<arm>/<pair>.json once judged (<arm>: the search, then @<budget>
where the budget is not 1250), the ticket it judged beside it (<pair>.safetensors), so a run resumes
pair by pair and anyone can judge the ticket again; its run folder under
benchmarks/runs/untuned/<arm>/ resumes its episodes. The LeRobot examples' pairs (the SmolVLA, the
UNet diffusion policies on reach and button-press-topdown) run in LeRobot's venv, their shipped
tickets judged beside ours; the DPPO-format checkpoints trained here (dppo_robomimic.py builds them
into runs/) in robosuite's. Results: benchmarks/results/untuned_bench.{md,json}.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from existence import FRESH_RANGES, HERE, fresh_check, run_folder, run_pair, table_row
from results_files import RESULTS, write_results

from goldenticket import kernels
from goldenticket.files import write_atomic
from goldenticket.report import rate_text
from goldenticket.tickets import Ticket

FRANKA = HERE.parent.parent / "shared" / "franka_sim"
ROWS = RESULTS / "untuned_bench"
PAIRS = {  # name -> (task, policy)
    "franka-1003": ("franka_pick:make_env", "franka_pick:make_policy_1003"),
    "franka-1002": ("franka_pick:make_env", "franka_pick:make_policy_1002"),
    "pixels-drawer-open": ("metaworld-pixels/drawer-open-v3", "metaworld-pixels/drawer-open-v3/flow"),
    "fetch-push": ("examples.fetch_push:make_env", "examples.fetch_push:make_policy"),
    "smolvla-drawer-open": ("metaworld-pixels/drawer-open-v3", "examples/smolvla_metaworld_policy"),
    "lerobot-reach": ("examples.lerobot_reach:make_env", "examples/lerobot_reach_policy"),
    "lerobot-button": ("examples.lerobot_button:make_env", "examples/lerobot_button_policy"),
    "dppo-lift": ("robomimic/lift", "runs/dppo-lift"),
    "dppo-can": ("robomimic/can", "runs/dppo-can"),
}
BUILT_BY = {f"dppo-{task}": f"robomimic-venv/bin/python benchmarks/dppo_robomimic.py --task {task}"
            for task in ("lift", "can")}  # policies trained here first (deterministic on one thread)
SHIPPED = {"smolvla-drawer-open": "examples/smolvla_metaworld_ticket.safetensors",  # the examples' tickets
           "lerobot-reach": "examples/lerobot_reach_ticket.safetensors"}
REFERENCES = {"authors-ticket": "the authors' shipped ticket",  # kind -> label of a ticket shipped before
              "shipped-ticket": "the example's ticket before this bench"}
SLOW = {"heldout": 50, "fresh_ranges": 1}  # franka_sim: 4-5 s an episode on one core
JUDGING = {name: SLOW if name.startswith("franka-") else {} for name in PAIRS}  # the verdict and fresh check
TOTAL = 1250  # the defaults' search and validation episodes at most
SEARCH_BUDGETS = {250: 100, 500: 350, TOTAL: 1100, 2500: 2350}  # that, halved -> the search's budget
SEARCHES = {"portfolio": {"method": "portfolio", "subspace": "full"},  # the `search` defaults
            "tiled": {"method": "cma-es", "subspace": "tiled"},  # CMA-ES, tiled: the default before
            "portfolio-from-tiled": {"method": "portfolio", "subspace": "full",  # its full search starting
                                     "optimizer": {"full_start": "tiled"}}}  # at the tiled one's best


def on_path(folder: Path) -> None:
    """`folder` importable here and in worker processes."""
    sys.path.insert(0, str(folder))
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(folder), os.environ.get("PYTHONPATH")]))


def arm_name(search: str, total: int) -> str:
    """Where a search within `total` search and validation episodes keeps its rows and runs."""
    return search if total == TOTAL else f"{search}@{total}"


def arm_of(arm: str) -> tuple[str, int]:
    """The search and budget of an `arm_name`."""
    search, _, total = arm.partition("@")
    return search, int(total or TOTAL)


def pair_row(name: str, search: str, total: int, workers: int) -> None:
    """The pair's row under `search` within `total` episodes, searched, judged and kept, unless kept
    already; its judged ticket is kept beside it (`<pair>.safetensors`)."""
    arm = arm_name(search, total)
    path = ROWS / arm / f"{name}.json"
    if not path.exists():
        task, policy = PAIRS[name]
        print(f"[{arm}] {name}", flush=True)
        runs = HERE / "runs" / "untuned" / arm
        budget = {} if total == TOTAL else {"budget": SEARCH_BUDGETS[total], "halving": True}
        summary = run_pair(task, policy, runs, workers, **SEARCHES[search] | budget | JUDGING[name])
        row = table_row(summary) | {"deliver": summary["deliver"]}
        Ticket.load(summary["best"]["ticket_path"]).save(path.with_suffix(".safetensors"))
        write_atomic(path, json.dumps(row, indent=2) + "\n")


def reference_row(name: str, search: str, workers: int) -> None:
    """The ticket shipped for the pair before any search here (`reference_ticket`), judged on the
    fresh ranges and kept, in `search`'s run folder (its base and zero episodes shared)."""
    kind, ticket = reference_ticket(name)
    if kind is None or (kept := ROWS / kind / f"{name}.json").exists():
        return
    task, policy = PAIRS[name]
    out = run_folder(HERE / "runs" / "untuned" / search, policy)
    out.mkdir(parents=True, exist_ok=True)
    path = ticket.save(out / f"{kind}.safetensors")
    ranges = FRESH_RANGES[: JUDGING[name].get("fresh_ranges", len(FRESH_RANGES))]
    row = {"ticket": ticket.id} | {key: fresh_check(path, policy, task, out, workers, i)
                                   for i, key in enumerate(ranges)}
    write_atomic(kept, json.dumps(row, indent=2) + "\n")


def reference_ticket(name: str) -> tuple[str | None, Ticket | None]:
    """(its kind, the ticket) shipped for the pair: the paper authors' for a franka_sim checkpoint,
    the example's own for a LeRobot example; (None, None) for the other pairs."""
    if name.startswith("franka-"):
        import franka_pick

        return "authors-ticket", Ticket(franka_pick.authors_ticket(int(name.removeprefix("franka-"))))
    if name in SHIPPED:
        return "shipped-ticket", Ticket.load(HERE.parent / SHIPPED[name])
    return None, None


def markdown(rows: dict, references: dict) -> str:
    lines = ["| pair | search | fresh range | base | zero ticket | delivered | p vs base | p vs zero | "
             "p below base | p below zero | search + validation episodes | episodes' time |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(name for name, _ in rows):
        for (pair, search), r in rows.items():
            if pair == name:
                cost = f"{r['search_and_validation']} | {r['episode_seconds'] / 60:.0f} min"
                lines += [range_line(name, f"{arm_label(search)}: {delivered(r)}", r[key], cost,
                                     r["deliver"] == "base") for key in FRESH_RANGES if key in r]
        for kind, label in REFERENCES.items():
            theirs = references.get(kind, {}).get(name, {})
            lines += [range_line(name, f"{label}, {theirs['ticket']}", theirs[key], "- | -")
                      for key in FRESH_RANGES if key in theirs]
    return "\n".join(lines) + "\n" + curve_markdown(rows)


def arm_label(arm: str) -> str:
    search, total = arm_of(arm)
    return search if total == TOTAL else f"{search} within {total}"


def curve_markdown(rows: dict) -> str:
    """The budget curve: per pair searched within more than one budget, and per search, what it
    delivers on each fresh range (or "-") within each budget."""
    curves: dict = {}
    for (name, arm), r in rows.items():
        search, total = arm_of(arm)
        curves.setdefault((name, search), {})[total] = r
    totals = sorted({total for curve in curves.values() for total in curve})
    kept = {key: curve for key, curve in curves.items() if len(curve) > 1}
    if not kept:
        return ""
    lines = ["", "The budget curve: what each search delivers within each number of search and validation "
             "episodes (its rate on each fresh range; the base or the zero ticket named where it is the "
             "one delivered):", "",
             "| pair | search | " + " | ".join(map(str, totals)) + " |", "|---|---|" + "---|" * len(totals)]
    for (name, search), curve in sorted(kept.items(), key=lambda item: item[0][0]):  # a pair's rows together
        cells = [curve_cell(curve[t]) if t in curve else "-" for t in totals]
        lines.append(f"| {name} | {search} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def curve_cell(row: dict) -> str:
    """A budget curve's cell: the delivered arm's rate on each fresh range, and which arm it is where
    it is the base or the zero ticket."""
    rates = " / ".join(f"{delivered_rate(row, key):.1%}" for key in FRESH_RANGES if key in row)
    arm = "the base" if row["deliver"] == "base" else "the zero ticket" if row["zero_ticket"] else ""
    return f"{rates} ({arm})" if arm else rates


def delivered_rate(row: dict, key: str) -> float:
    """What the delivered arm succeeds on a fresh range: the base's rate where the base is delivered."""
    fresh = row[key]
    return fresh["base"]["success_rate"] if row["deliver"] == "base" else fresh["success_rate"]


def delivered(row: dict) -> str:
    """What the job tells the user to run: the best ticket, the zero ticket, or the base where no
    ticket judged beat it on the held-out seeds."""
    best = "the zero ticket" if row["zero_ticket"] else f"ticket {row['ticket']}"
    return f"the base (its best, {best}, was not above it)" if row["deliver"] == "base" else best


def range_line(name: str, label: str, f: dict, cost: str, base: bool = False) -> str:
    """One delivered arm's line on one fresh range: base, zero ticket and it (the base itself where
    `base`), its one-sided p-values of being better (vs) and worse (below), its cost."""
    tests = ("p_vs_base", "p_vs_zero", "p_below_base", "p_below_zero")
    p_values = " | ".join("-" if base else f"{f[key]:.2g}" for key in tests)
    return (f"| {name} | {label} | {f['seeds'][0]}:{f['seeds'][1] + 1} | {rate_text(f['base'])} | "
            f"{rate_text(f['zero'])} | {rate_text(f['base'] if base else f)} | {p_values} | {cost} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", choices=list(PAIRS), default=list(PAIRS))
    parser.add_argument("--search", nargs="+", choices=list(SEARCHES), default=["portfolio"])
    parser.add_argument("--budgets", nargs="+", type=int, choices=list(SEARCH_BUDGETS), default=[TOTAL],
                        help="search and validation episodes at most")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    unbuilt = [name for name in args.pairs if name in BUILT_BY and not Path(PAIRS[name][1]).is_dir()]
    if unbuilt:
        parser.error(f"no {PAIRS[unbuilt[0]][1]}/ here; build it first: {BUILT_BY[unbuilt[0]]}")
    kernels.restart_pinned([PAIRS[name][0] for name in args.pairs])  # robomimic's, as the CLI pins
    on_path(FRANKA)
    on_path(HERE.parent)  # the examples' policies and envs, named as the CLI names them
    for name in args.pairs:
        for search in args.search:
            for total in args.budgets:
                pair_row(name, search, total, args.workers)
        reference_row(name, args.search[0], args.workers)
    kept = {(p.stem, p.parent.name): json.loads(p.read_text())
            for p in sorted(ROWS.glob("*/*.json"), key=lambda p: arm_of(p.parent.name))
            if arm_of(p.parent.name)[0] in SEARCHES}
    references = {kind: {p.stem: json.loads(p.read_text()) for p in sorted(ROWS.glob(f"{kind}/*.json"))}
                  for kind in REFERENCES}
    record = {"pairs": {f"{n}/{s}": r for (n, s), r in kept.items()}}
    record |= {kind.replace("-", "_"): rows for kind, rows in references.items()}
    write_results("untuned_bench", record, markdown(kept, references))


if __name__ == "__main__":
    main()

"""Multi-task tickets on MT10: per-task tickets vs one multi-task ticket vs the cover set.

    python benchmarks/multitask.py [--policy metaworld/mt10/flow] [--workers 2]

On the bundled multi-task policy, with the same search budget for both approaches:
1. `goldenticket transfer`: one CEM-with-racing search per task (BUDGET episodes on 20 search
   seeds each), every ticket judged on every task's first 100 held-out seeds: the transfer
   matrix and its greedy cover.
2. `goldenticket search --task ... (x10)`: one ticket for all ten tasks (10 x BUDGET episodes,
   5 search seeds per task), judged per task on the same 100 held-out seeds; the best by average.
3. The verdict on 200 fresh held-out seeds per task (1000100..1000299, used by no selection):
   base, zero ticket, the task's own ticket, the multi-task ticket, and the cover's switching
   table (each task runs the ticket the cover assigns it, or the base).

Every run lives in `--runs` (run stores, resumable per episode). Writes
benchmarks/results/multitask.{md,json,png} and the transfer heatmap multitask_transfer.png.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from build_zoo import MT10
from results_files import RESULTS, write_results

from goldenticket.config import EngineOptions, SearchConfig
from goldenticket.evaluation import ZERO, Arm, Evaluator, judge, to_dicts
from goldenticket.job import find_golden_tickets
from goldenticket.multitask import transfer
from goldenticket.noise import Constant, Gaussian
from goldenticket.plots import transfer_png
from goldenticket.policies import load_policy
from goldenticket.report import gain_text, p_vs_base, rate_text, short_task
from goldenticket.store import RunStore
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket, zero_ticket

HERE = Path(__file__).parent
TASKS = tuple(f"metaworld/{t}" for t in MT10)
METHOD, BUDGET = "cem-racing", 500  # search method and episodes per task (as recorded; not the defaults)
FRESH = list(range(1_000_100, 1_000_300))
ARMS = ("base", "zero", "own ticket", "multi-task ticket", "cover")


def fresh_verdict(policy_name: str, tickets: dict[str, dict[str, Ticket | None]], runs: Path,
                  workers: int) -> dict:
    """Per task, on FRESH seeds: base, zero and each role's ticket (None: the base itself),
    p-values Holm-adjusted over the roles per task."""
    policy = load_policy(policy_name)
    zero = Constant(zero_ticket(policy.noise_shape).noise)
    tasks = [get_task(t) for t in TASKS]
    out = {}
    with RunStore(runs / "fresh.sqlite") as store, \
            Evaluator.open(policy_name, tasks, EngineOptions(workers=workers), store,
                           loaded=policy) as evaluator, \
            evaluator.progress(len(FRESH) * len(ARMS) * len(TASKS), "fresh held-out verdict"):
        for task in TASKS:
            roles = {Arm.ticket(role): Gaussian(0) if t is None else Constant(t.noise)
                     for role, t in tickets[task].items()}
            out[task] = to_dicts(judge(evaluator, {ZERO: zero} | roles, FRESH, Gaussian(0), task).rows)
    return out


def markdown(results: dict, wall: float, policy: str) -> str:
    mt, study, fresh = results["multitask"], results["transfer"], results["fresh"]
    cover = study["cover"]
    lines = [f"Regenerate: `python benchmarks/multitask.py --policy {policy}` ({wall / 60:.0f} min here, "
             "2 workers).", "",
             f"Search budget: {BUDGET} episodes per task for each per-task ticket; "
             f"{BUDGET * len(TASKS)} for the "
             f"multi-task ticket ({mt['search_episodes']} used). Cover: {len(cover['tickets'])} ticket(s) "
             f"({', '.join(cover['tickets'])}).", "",
             f"### Fresh held-out seeds {FRESH[0]}:{FRESH[-1] + 1} ({len(FRESH)} per task): success, 95% "
             "Wilson interval; p vs base (one-sided exact paired, Holm over the 3 ticket arms)", "",
             "| task | " + " | ".join(ARMS) + " |", "|---|" + "---|" * len(ARMS)]
    for task, arms in fresh.items():
        cells = [rate_text(arms[a]) + (f", p={p_vs_base(arms[a]):.2g}" if a not in ("base", "zero") else "")
                 for a in ARMS]
        lines.append(f"| {short_task(task)} | " + " | ".join(cells) + " |")
    means = {a: np.mean([fresh[t][a]["success_rate"] for t in fresh]) for a in ARMS}
    lines.append("| **mean** | " + " | ".join(f"**{means[a]:.1%}**" for a in ARMS) + " |")
    wins = {a: sum(fresh[t][a].get("golden", False) for t in fresh) for a in ARMS[2:]}
    worse = {a: sum(fresh[t][a]["success_rate"] < fresh[t]["base"]["success_rate"] for t in fresh)
             for a in ARMS[2:]}
    lines += ["", "Tasks with a significant gain over the base (lower than the base, not necessarily "
              "significantly): " + "; ".join(f"{a} {wins[a]} ({worse[a]})" for a in ARMS[2:]) + ".", "",
              "### Transfer matrix (first 100 held-out seeds): gain over base, points; "
              "* Holm-adjusted p < 0.05", "",
              "| ticket (found on) | " + " | ".join(short_task(t) for t in study["tasks"]) + " |",
              "|---|" + "---|" * len(study["tasks"])]
    for ticket, found in study["tickets"].items():
        row = study["cells"][ticket]
        gains = " | ".join(gain_text(row[t]["gain"], row[t]["significant"]) for t in study["tasks"])
        lines.append(f"| {ticket} ({', '.join(map(short_task, found))}) | {gains} |")
    lines += ["", "### The multi-task search's own verdict (first 100 held-out seeds): best ticket "
              f"{mt['best']}", "",
              "| task | base | zero | multi-task ticket | regresses |", "|---|---|---|---|---|"]
    for task, arms in [*mt["tasks"].items(), ("average", mt["average"])]:
        flag = "yes" if task in mt["regressions"].get(mt["best"], []) else ""
        lines.append(f"| {short_task(task)} | {rate_text(arms['base'])} | {rate_text(arms['zero'])} | "
                     f"{rate_text(arms[mt['best']])} | {flag} |")
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fresh = results["fresh"]
    colors = {"base": "0.45", "zero": "tab:blue", "own ticket": "tab:green", "multi-task ticket": "goldenrod",
              "cover": "tab:purple"}
    fig = Figure(figsize=(13, 5))
    ax = fig.subplots()
    width = 0.8 / len(ARMS)
    for i, arm in enumerate(ARMS):
        x = np.arange(len(fresh)) + (i - len(ARMS) / 2 + 0.5) * width
        rates = np.array([fresh[t][arm]["success_rate"] for t in fresh])
        low = rates - [fresh[t][arm]["ci_low"] for t in fresh]
        high = np.array([fresh[t][arm]["ci_high"] for t in fresh]) - rates
        ax.bar(x, rates, width, color=colors[arm], label=arm, yerr=[low, high], capsize=2)
    ax.set_xticks(range(len(fresh)), [short_task(t) for t in fresh], rotation=20, ha="right")
    ax.set(ylim=(0, 1.05), ylabel="success (95% Wilson)",
           title=f"{results['policy']} on MT10: fresh held-out seeds ({len(FRESH)} per task)")
    ax.legend(ncols=len(ARMS), fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.3))
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="metaworld/mt10/flow")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runs", type=Path, default=HERE / "runs" / "multitask")
    args = parser.parse_args()
    runs = args.runs / args.policy.replace("/", "_")
    start = time.perf_counter()
    study = transfer(SearchConfig(args.policy, TASKS, METHOD, BUDGET, heldout=100, workers=args.workers),
                     runs / "transfer")
    mt = find_golden_tickets(SearchConfig(args.policy, TASKS, METHOD, BUDGET * len(TASKS), search_seeds=5,
                                          heldout=100, top_k=3, workers=args.workers), runs / "multitask")
    mt = mt.to_dict()
    searches = runs / "transfer" / "search"
    own = {task: Ticket.load(searches / task.replace("/", "_") / "tickets" / f"{tid}.safetensors")
           for tid, tasks in study.tickets.items() for task in tasks}
    multi = Ticket.load(runs / "multitask" / "tickets" / f"{mt['best']}.safetensors")
    by_id = {t.id: t for t in own.values()}
    roles = {t: {"own ticket": own[t], "multi-task ticket": multi,
                 "cover": by_id.get(study.cover.table[t][0])} for t in TASKS}
    fresh = fresh_verdict(args.policy, roles, runs, args.workers)
    wall = time.perf_counter() - start
    results = {"policy": args.policy, "transfer": study.to_dict(), "multitask": mt, "fresh": fresh,
               "wall_seconds": wall}
    write_results("multitask", results, markdown(results, wall, args.policy),
                  lambda path: plot(results, path))
    transfer_png(study, RESULTS / "multitask_transfer.png")


if __name__ == "__main__":
    main()

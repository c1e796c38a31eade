"""Multi-task tickets: per-task tickets vs one multi-task ticket vs the cover set, on a multi-task
policy's tasks.

    python benchmarks/multitask.py [--policy metaworld/mt10/flow] [--workers 2]     # MT10
    lerobot-venv/bin/python benchmarks/multitask.py --study libero-object --workers 1  # LIBERO-Object

A study (STUDIES) names the policy, its tasks, the search and the seeds; with the same search
budget per task for both approaches:
1. `goldenticket transfer`: one search per task (the study's budget on 20 search seeds each),
   every ticket judged on every task's first held-out seeds: the transfer matrix and its greedy
   cover.
2. `goldenticket search --task ... (one per task)`: one ticket for all tasks (the budget times the
   tasks, 5 search seeds per task), judged per task on the same held-out seeds; the best by average.
3. The verdict on fresh held-out seeds per task (used by no selection): base, zero ticket, the
   task's own ticket, the multi-task ticket, and the cover's switching table (each task runs the
   ticket the cover assigns it, or the base).

`mt10`: the bundled MT10 policy, CEM with racing, 500 episodes a task, 100 held-out seeds, 200
fresh (1000100..1000299), as recorded. `libero-object`: the shipped LIBERO-Object SmolVLA
(`examples/smolvla_libero_policy/`, its 64 x 64 cameras) on its five tasks, the `search` defaults
within 250 episodes of search and validation a task, 50 held-out and 50 fresh seeds (1005000..1005049):
a LIBERO episode takes about 15 s of a core here.
Every run lives in `--runs` (run stores, resumable per episode). Writes
benchmarks/results/<study's results>.{md,json,png} and the transfer heatmap <results>_transfer.png.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from build_zoo import MT10
from results_files import RESULTS, write_results

from goldenticket.config import EngineOptions, SearchConfig
from goldenticket.evaluation import ZERO, Arm, Evaluator, judge, to_dicts
from goldenticket.job import find_golden_tickets
from goldenticket.multitask import TransferStudy, transfer
from goldenticket.noise import Constant, Gaussian
from goldenticket.plots import transfer_png
from goldenticket.policies import load_policy
from goldenticket.report import gain_text, p_vs_base, rate_text, short_task
from goldenticket.store import RunStore
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket, zero_ticket

HERE = Path(__file__).parent
ARMS = ("base", "zero", "own ticket", "multi-task ticket", "cover")


@dataclass(frozen=True)
class Study:
    """A multi-task policy on its tasks, the search each arm gets and the seeds it is judged on."""

    policy: str
    tasks: tuple[str, ...]
    label: str  # the tasks, in titles
    method: str | None  # None: the `search` default (and its halving)
    budget: int  # search episodes per task; the multi-task search gets this times the tasks
    heldout: int  # held-out seeds per task: the transfer matrix and the multi-task search's verdict
    fresh: range  # the final verdict's seeds, after the held-out ones
    results: str  # benchmarks/results/<results>.{md,json,png}
    command: str  # what regenerates it
    env_option: dict | None = None  # the tasks' env options (LeRobot's LIBERO)

    def search(self) -> dict:
        """SearchConfig's settings for a search of this study, beside its budget and seeds."""
        return ({"method": self.method} if self.method else {}) | {"env_option": self.env_option}


def mt10(policy: str | None) -> Study:
    """The bundled MT10 policy (or `policy`) on the ten tasks, as recorded."""
    policy = policy or "metaworld/mt10/flow"
    return Study(policy, tuple(f"metaworld/{t}" for t in MT10), "MT10", "cem-racing", 500, 100,
                 range(1_000_100, 1_000_300), "multitask",
                 f"python benchmarks/multitask.py --policy {policy}")


def libero_object(policy: str | None) -> Study:
    """The shipped LIBERO-Object SmolVLA (LeRobot's venv); its recipe names its tasks and cameras."""
    sys.path.insert(0, str(HERE.parent / "examples"))
    from smolvla_libero_train import RECIPE  # the examples folder is not a package

    shipped = str(RECIPE.policy_dir.relative_to(HERE.parent))  # run from the repository's root
    return Study(policy or shipped, RECIPE.tasks, "LIBERO-Object", None, 100, 50,
                 range(1_005_000, 1_005_050), "libero_multitask",
                 "lerobot-venv/bin/python benchmarks/multitask.py --study libero-object",
                 RECIPE.task_options)


STUDIES = {"mt10": mt10, "libero-object": libero_object}


def fresh_verdict(study: Study, tickets: dict[str, dict[str, Ticket | None]], runs: Path,
                  workers: int) -> dict:
    """Per task, on the study's fresh seeds: base, zero and each role's ticket (None: the base
    itself), p-values Holm-adjusted over the roles per task."""
    policy = load_policy(study.policy)
    zero = Constant(zero_ticket(policy.noise_shape).noise)
    tasks = [get_task(t, env_options=study.env_option) for t in study.tasks]
    out = {}
    with RunStore(runs / "fresh.sqlite") as store, \
            Evaluator.open(study.policy, tasks, EngineOptions(workers=workers, env_option=study.env_option),
                           store, loaded=policy) as evaluator, \
            evaluator.progress(len(study.fresh) * len(ARMS) * len(tasks), "fresh held-out verdict"):
        for task in study.tasks:
            roles = {Arm.ticket(role): Gaussian(0) if t is None else Constant(t.noise)
                     for role, t in tickets[task].items()}
            out[task] = to_dicts(judge(evaluator, {ZERO: zero} | roles, list(study.fresh), Gaussian(0),
                                       task).rows)
    return out


def markdown(results: dict, study: Study, workers: int) -> str:
    mt, matrix, fresh = results["multitask"], results["transfer"], results["fresh"]
    cover, fresh_seeds = matrix["cover"], study.fresh
    lines = [f"Regenerate: `{study.command}` ({results['wall_seconds'] / 60:.0f} min here, {workers} "
             "worker(s); a resumed run counts only its last part).", "",
             f"Search: {study.method or results['multitask']['method']}, {study.budget} search episodes "
             f"per task for each per-task ticket; {study.budget * len(study.tasks)} for the "
             f"multi-task ticket ({mt['search_episodes']} used). Cover: {len(cover['tickets'])} ticket(s) "
             f"({', '.join(cover['tickets'])}).", "",
             f"### Fresh held-out seeds {fresh_seeds.start}:{fresh_seeds.stop} ({len(fresh_seeds)} per "
             "task): success, 95% Wilson interval; p vs base (one-sided exact paired, Holm over the 3 "
             "ticket arms)", "",
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
              f"### Transfer matrix (first {study.heldout} held-out seeds): gain over base, points; "
              "* Holm-adjusted p < 0.05", "",
              "| ticket (found on) | " + " | ".join(short_task(t) for t in matrix["tasks"]) + " |",
              "|---|" + "---|" * len(matrix["tasks"])]
    for ticket, found in matrix["tickets"].items():
        row = matrix["cells"][ticket]
        gains = " | ".join(gain_text(row[t]["gain"], row[t]["significant"]) for t in matrix["tasks"])
        lines.append(f"| {ticket} ({', '.join(map(short_task, found))}) | {gains} |")
    lines += ["", f"### The multi-task search's own verdict (first {study.heldout} held-out seeds): best "
              f"ticket {mt['best']}", "",
              "| task | base | zero | multi-task ticket | regresses |", "|---|---|---|---|---|"]
    for task, arms in [*mt["tasks"].items(), ("average", mt["average"])]:
        flag = "yes" if task in mt["regressions"].get(mt["best"], []) else ""
        lines.append(f"| {short_task(task)} | {rate_text(arms['base'])} | {rate_text(arms['zero'])} | "
                     f"{rate_text(arms[mt['best']])} | {flag} |")
    return "\n".join(lines) + "\n"


def plot(results: dict, study: Study, path: Path) -> None:
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
           title=f"{results['policy']} on {study.label}: fresh held-out seeds ({len(study.fresh)} per task)")
    ax.legend(ncols=len(ARMS), fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.3))
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", choices=list(STUDIES), default="mt10")
    parser.add_argument("--policy", default=None, help="the study's policy (mt10: metaworld/mt10/flow)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runs", type=Path, default=HERE / "runs" / "multitask")
    args = parser.parse_args()
    study = STUDIES[args.study](args.policy)
    results, matrix = run(study, args.runs / args.study / Path(study.policy).name, args.workers)
    write_results(study.results, results, markdown(results, study, args.workers),
                  lambda path: plot(results, study, path))
    transfer_png(matrix, RESULTS / f"{study.results}_transfer.png")


def run(study: Study, runs: Path, workers: int) -> tuple[dict, TransferStudy]:
    """The study's searches, transfer matrix, cover and fresh verdict, resumably in `runs`: the
    results and the transfer matrix."""
    start, tasks = time.perf_counter(), study.tasks
    matrix = transfer(SearchConfig(study.policy, tasks, budget=study.budget, heldout=study.heldout,
                                   workers=workers, **study.search()), runs / "transfer")
    multi_cfg = SearchConfig(study.policy, tasks, budget=study.budget * len(tasks), search_seeds=5,
                             heldout=study.heldout, top_k=3, workers=workers, **study.search())
    mt = find_golden_tickets(multi_cfg, runs / "multitask").to_dict()
    searches = runs / "transfer" / "search"
    own = {task: Ticket.load(searches / task.replace("/", "_") / "tickets" / f"{tid}.safetensors")
           for tid, found in matrix.tickets.items() for task in found}
    multi = Ticket.load(runs / "multitask" / "tickets" / f"{mt['best']}.safetensors")
    by_id = {t.id: t for t in own.values()}
    roles = {t: {"own ticket": own[t], "multi-task ticket": multi,
                 "cover": by_id.get(matrix.cover.table[t][0])} for t in tasks}
    fresh = fresh_verdict(study, roles, runs, workers)
    return {"policy": study.policy, "transfer": matrix.to_dict(), "multitask": mt, "fresh": fresh,
            "wall_seconds": time.perf_counter() - start}, matrix


if __name__ == "__main__":
    main()

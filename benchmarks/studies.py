"""Three studies on the bundled flow policies of the three tasks with the lowest base success.

    python benchmarks/studies.py [--workers 2]      # resumable; writes benchmarks/results/studies.*

- Pareto: random search over 100 tickets x 10 search seeds, objectives success and speed; the
  front re-judged on 100 held-out seeds beside base and zero (`search --objective success
  --front-objective speed`).
- Mixture: the Pareto run's 3 best tickets by search success, the best of them alone, a mixture of
  the 3 (`evaluate --mixture`) and base, on 200 other held-out seeds: success and diversity.
- Sub-space: CEM with racing over the full ticket, one tiled action vector, and the gripper
  channel only (`--subspace full|tiled|channels:3`), at budgets 100, 300 and 1000 search
  episodes; held-out success of the top ticket on 100 held-out seeds.

Every run lives in `--runs` (run stores, resumable per episode).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from results_files import write_results

from goldenticket.config import EvaluateConfig, SearchConfig
from goldenticket.evaluation import to_dicts
from goldenticket.job import find_golden_tickets
from goldenticket.job.evaluate import evaluate_tickets
from goldenticket.report import p_vs_base, rate_text

HERE = Path(__file__).parent
TASKS = ("pick-place-v3", "reach-v3", "drawer-open-v3")
SUBSPACES = ("full", "tiled", "channels:3")
BUDGETS = (100, 300, 1000)
MIXTURE_SEEDS = range(1_000_200, 1_000_400)


def pareto(task: str, runs: Path, workers: int) -> dict:
    cfg = SearchConfig(f"metaworld/{task}/flow", f"metaworld/{task}", method="rs", budget=1000,
                       search_seeds=10, heldout=100, top_k=3, stop_after_perfect=None, workers=workers,
                       front_objective="speed", validation_seeds=0, halving=False)
    summary = find_golden_tickets(cfg, runs / f"pareto_{task}")
    return summary.front.to_dict() | {"summary": summary.to_dict()}


def mixture(task: str, pareto_summary: dict, workers: int) -> dict:
    paths = [Path(t["ticket_path"]) for t in pareto_summary["tickets"]]
    cfg = EvaluateConfig(f"metaworld/{task}/flow", f"metaworld/{task}", tuple(map(str, paths)), MIXTURE_SEEDS,
                         workers=workers, mixture=True)
    rows = to_dicts(evaluate_tickets(cfg))
    best = max((label for label in rows if label not in ("base", "zero", "mixture")),
               key=lambda label: rows[label]["success_rate"])
    return {"base": rows["base"], "best ticket": rows[best] | {"ticket_id": best}, "mixture": rows["mixture"],
            "tickets": [p.stem for p in paths]}


def subspace(task: str, runs: Path, workers: int) -> dict:
    curves = {}
    for space in SUBSPACES:
        curves[space] = []
        for budget in BUDGETS:
            cfg = SearchConfig(f"metaworld/{task}/flow", f"metaworld/{task}", "cem-racing", budget,
                               heldout=100, top_k=1, workers=workers, subspace=space, validation_seeds=0)
            s = find_golden_tickets(cfg, runs / f"subspace_{task}_{space.replace(':', '')}_{budget}")
            curves[space].append({"budget": budget, "episodes": s.run.search_episodes,
                                  "best": s.best.to_dict(), "base": s.base.to_dict()})
    return curves


def markdown(results: dict, wall: float) -> str:
    lines = [f"Regenerate: `python benchmarks/studies.py` ({wall / 60:.0f} min here, 2 workers).", "",
             "### Pareto: success vs speed (held-out, 100 seeds)", "",
             "| task | arm | success | speed |", "|---|---|---|---|"]
    for task, study in results["pareto"].items():
        for label, row in study["heldout"].items():
            lines.append(f"| {task} | {label} | {rate_text(row)} | {row['scores']['speed']:.3f} |")
    lines += ["", "### Mixture of the 3 best tickets (200 other held-out seeds)", "",
              "| task | arm | success | p vs base | diversity |", "|---|---|---|---|---|"]
    for task, arms in results["mixture"].items():
        for label in ("base", "best ticket", "mixture"):
            row = arms[label]
            p = "-" if p_vs_base(row) is None else f"{p_vs_base(row):.3g}"
            lines.append(f"| {task} | {label} | {rate_text(row)} | {p} | {row['diversity']:.3f} |")
    lines += ["", "### Sub-space search: held-out success of the top ticket (100 seeds)", "",
              "| task | sub-space | " + " | ".join(f"budget {b}" for b in BUDGETS) + " |",
              "|---|---|" + "---|" * len(BUDGETS)]
    for task, curves in results["subspace"].items():
        for space, points in curves.items():
            lines.append(f"| {task} | {space} | " + " | ".join(rate_text(p["best"]) for p in points) + " |")
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 3.6 * len(TASKS)))
    axes = fig.subplots(len(TASKS), 3)
    for row, task in zip(axes, TASKS, strict=True):
        front = results["pareto"][task]
        for label, arm in front["heldout"].items():
            color = {"base": "0.45", "zero": "tab:blue"}.get(label, "goldenrod")
            row[0].scatter(arm["success_rate"], arm["scores"]["speed"], color=color)
            row[0].annotate(label, (arm["success_rate"], arm["scores"]["speed"]), fontsize="x-small")
        row[0].set(title=f"{task}: Pareto front (held-out)", xlabel="success", ylabel="speed")
        arms = results["mixture"][task]
        labels = ["base", "best ticket", "mixture"]
        row[1].bar(labels, [arms[k]["success_rate"] for k in labels],
                   color=["0.45", "goldenrod", "tab:green"])
        twin = row[1].twinx()
        twin.plot(labels, [arms[k]["diversity"] for k in labels], "ko-")
        row[1].set(title=f"{task}: success (bars), diversity (dots)", ylim=(0, 1))
        for space, points in results["subspace"][task].items():
            row[2].plot([p["episodes"] for p in points], [p["best"]["success_rate"] for p in points], "o-",
                        label=space)
        row[2].axhline(points[0]["base"]["success_rate"], color="0.45", linestyle="--", label="base")
        row[2].set(title=f"{task}: sub-space search", xlabel="search episodes", ylabel="held-out success",
                   xscale="log")
        row[2].legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runs", type=Path, default=HERE / "runs" / "studies")
    args = parser.parse_args()
    start = time.perf_counter()
    results = {"pareto": {}, "mixture": {}, "subspace": {}}
    for task in TASKS:
        front = pareto(task, args.runs, args.workers)
        results["pareto"][task] = {k: v for k, v in front.items() if k != "summary"}
        results["mixture"][task] = mixture(task, front["summary"], args.workers)
        results["subspace"][task] = subspace(task, args.runs, args.workers)
    wall = time.perf_counter() - start
    write_results("studies", results | {"wall_seconds": wall}, markdown(results, wall),
                  lambda path: plot(results, path))


if __name__ == "__main__":
    main()

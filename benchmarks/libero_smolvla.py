"""The shipped LIBERO-Object SmolVLA (`examples/smolvla_libero_policy/`), measured: its base and
zero ticket on each task it was trained on, on held-out seeds. In LeRobot's venv (README, "LeRobot"):

    lerobot-venv/bin/python benchmarks/libero_smolvla.py [--seeds 1005000:1005020] [--workers 1]

Each task runs as `goldenticket evaluate --policy examples/smolvla_libero_policy --task
libero/object/<id> --env-option observation_height=64 --env-option observation_width=64 --seeds
A:B` runs it (base: fresh Gaussian noise from seed 0; the zero ticket w = 0), its episodes kept in
benchmarks/runs/libero-smolvla/<task>.sqlite, so a stopped run resumes episode by episode. Writes
benchmarks/results/libero_smolvla.{md,json} as each task ends.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from results_files import RESULTS, write_results

from goldenticket.config import EvaluateConfig, seed_range
from goldenticket.evaluation import BASE, ZERO
from goldenticket.job.evaluate import evaluate_tickets
from goldenticket.report import rate_text
from goldenticket.store import RunStore

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent / "examples"))
from smolvla_libero_train import RECIPE  # noqa: E402  (the examples folder is not a package)

RUNS = HERE / "runs" / "libero-smolvla"


def measure(task: str, seeds: range, workers: int) -> dict:
    """Base and zero ticket on `seeds` of one task, and the episodes' wall time."""
    cfg = EvaluateConfig(str(RECIPE.policy_dir), task, seeds=seeds, workers=workers,
                         env_option=RECIPE.task_options)
    RUNS.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with RunStore(RUNS / f"{task.replace('/', '_')}.sqlite") as store:
        rows = evaluate_tickets(cfg, store)
    return {"task": task, "seeds": [seeds.start, seeds.stop], "base": rows[BASE].to_dict(),
            "zero": rows[ZERO].to_dict(), "wall_s": round(time.perf_counter() - start), "workers": workers}


def markdown(rows: list[dict]) -> str:
    first = rows[0]["seeds"]
    lines = [f"Held-out seeds {first[0]}:{first[1]} of each task (95% Wilson intervals); p: one-sided exact "
             "paired test of the zero ticket above the base.", "",
             "| task | base | zero ticket | p | wall time |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['task']} | {rate_text(r['base'])} | {rate_text(r['zero'])} | "
                     f"{r['zero']['p_vs_base']:.2g} | {r['wall_s'] / 60:.0f} min, {r['workers']} worker(s) |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=seed_range, default=range(1_005_000, 1_005_020),
                        help="held-out seeds A:B (default 1005000:1005020)")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    first, last = args.seeds.start, args.seeds.stop
    path, rows = RESULTS / "libero_smolvla.json", []
    kept = {r["task"]: r for r in json.loads(path.read_text())["tasks"]} if path.is_file() else {}
    for task in RECIPE.tasks:
        row = kept.get(task)
        if row is None or row["seeds"] != [first, last]:
            row = measure(task, args.seeds, args.workers)
        rows.append(row)
        policy = str(RECIPE.policy_dir.relative_to(HERE.parent))
        record = {"policy": policy, "env_option": RECIPE.task_options, "tasks": rows}
        write_results("libero_smolvla", record, markdown(rows))
        print(f"{task}: base {rate_text(row['base'])}, zero {rate_text(row['zero'])} ({row['wall_s']} s)",
              flush=True)


if __name__ == "__main__":
    main()

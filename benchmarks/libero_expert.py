"""The LIBERO-Object scripted expert, measured: success, steps and time per task, without habits and
with a demonstrator's habits. In LeRobot's venv (README, "LeRobot"):

    lerobot-venv/bin/python benchmarks/libero_expert.py [--tasks 0 1 ...] [--seeds 10]

Each of LIBERO-Object's tasks runs the expert (`goldenticket.tasks.libero_experts`) on its first
--seeds training seeds, as `goldenticket.train.collect_demos` runs it (the same experts, habits drawn
from one seeded generator per task and style, the same episodes), with 32 x 32 camera frames, which
the expert does not read. Writes benchmarks/results/libero_expert.{md,json} as each task ends;
a task measured there before (with the same styles and seeds) is kept, not run again.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from results_files import RESULTS, write_results

from goldenticket.seeds import seeds_in
from goldenticket.tasks import get_task
from goldenticket.train import DemoStyle, _expert_episode, _experts

STYLES = {"no habits": DemoStyle(),
          "habits": DemoStyle(grasp_offset=0.02, action_noise=0.1, goal_offset=0.02)}
SMALL = {"observation_height": 32, "observation_width": 32}  # frames the expert does not read


def measure(task_id: int, style: DemoStyle, seeds: range) -> dict:
    """The expert's episodes on `seeds` of one task: successes, steps and seconds (reset included)."""
    task = get_task(f"libero/object/{task_id}", env_options=SMALL)
    env = task.make_env()
    experts, rng = _experts(task, env), np.random.default_rng(0)
    episodes = []
    for seed in seeds:
        start = time.perf_counter()
        expert = experts(*style.habit(rng))
        _, actions, success = _expert_episode(expert, env, task, seed, style.action_noise, rng)
        episodes.append({"seed": seed, "success": bool(success), "steps": len(actions),
                         "seconds": round(time.perf_counter() - start, 2)})
    return {"task": task.name, "instruction": task.instruction, "episodes": episodes}


def kept_rows(styles: dict, seeds: range) -> dict:
    """The tasks measured before with these styles on these seeds: {task: {style: row}}."""
    path = RESULTS / "libero_expert.json"
    record = json.loads(path.read_text()) if path.is_file() else {}
    if record.get("styles") != styles:
        return {}
    return {name: by_style for name, by_style in record["tasks"].items()
            if all([e["seed"] for e in r["episodes"]] == list(seeds) for r in by_style.values())}


def markdown(rows: dict) -> str:
    lines = ["| task | instruction | " + " | ".join(STYLES)
             + " | steps (no habits) | s an episode (no habits) |",
             "|---|---|" + "---|" * (len(STYLES) + 2)]
    for name, by_style in rows.items():
        first = next(iter(by_style.values()))
        counts = [f"{sum(e['success'] for e in r['episodes'])}/{len(r['episodes'])}"
                  for r in by_style.values()]
        steps = [e["steps"] for e in first["episodes"] if e["success"]]
        seconds = np.mean([e["seconds"] for e in first["episodes"]])
        lines.append(f"| {name} | {first['instruction']} | {' | '.join(counts)} | "
                     f"{min(steps, default=0)}-{max(steps, default=0)} | {seconds:.1f} |")
    styles = "; ".join(f"{label}: {style.describe()}" for label, style in STYLES.items())
    return "\n".join(lines) + f"\n\n{styles}.\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", type=int, default=list(range(10)), choices=range(10))
    parser.add_argument("--seeds", type=int, default=10, help="first training seeds per task")
    args = parser.parse_args()
    seeds = seeds_in("train", args.seeds)
    styles = {label: style.describe() for label, style in STYLES.items()}
    rows = kept_rows(styles, seeds)
    for task_id in args.tasks:  # the results gain each task as it ends
        name = f"libero/object/{task_id}"
        if name in rows:
            continue
        rows[name] = {label: measure(task_id, style, seeds) for label, style in STYLES.items()}
        rows = dict(sorted(rows.items(), key=lambda item: int(item[0].rsplit("/", 1)[1])))
        seconds = sum(e["seconds"] for by_style in rows.values() for r in by_style.values()
                      for e in r["episodes"])
        record = {"styles": styles, "tasks": rows, "episode_seconds": round(seconds)}
        table = markdown(rows)
        write_results("libero_expert", record, table)
        print(table.splitlines()[-3], flush=True)


if __name__ == "__main__":
    main()

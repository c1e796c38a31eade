"""Train the policy zoo into the package: a flow and a DDIM policy per MT10 task, one multi-task
flow and DDIM policy for all ten (`metaworld/mt10/<kind>`, told the task by a one-hot), and a flow
and a DDIM policy for robomimic's Lift, Can, Square and Transport (run in robosuite's venv: README,
"LeRobot, robomimic").

    python benchmarks/build_zoo.py [--jobs 2] [--only reach-v3 ...]   # or --jobs 1 --workers 2
    python benchmarks/build_zoo.py --multitask [--only flow]   # the two MT10 policies
    robomimic-venv/bin/python benchmarks/build_zoo.py --robomimic [--only robomimic/lift [flow]]
    python benchmarks/build_zoo.py --remeasure   # re-measure every card's base and zero ticket

Resumable: a policy folder that already has its card.json is kept, and a killed measurement resumes
(`train.build_policy`). Each recipe says why the policy is imperfect (few, noisy, multimodal
demonstrations); the model card records it with the measured held-out success and the exact
`goldenticket train` command that rebuilds it.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
from dataclasses import asdict

from goldenticket import kernels
from goldenticket.config import TrainConfig
from goldenticket.policies import BUNDLED_DIR, MLPPolicy
from goldenticket.tasks import get_task
from goldenticket.train import DemoStyle, build_multitask_policy, build_policy, measure, write_card

MT10 = ("reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3", "drawer-close-v3",
        "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3", "window-close-v3")
HABIT = DemoStyle(grasp_offset=0.04, action_noise=0.15)
# (demos, style); easy tasks get fewer, noisier demos, peg insertion a smaller habit spread.
FEW_NOISY = DemoStyle(grasp_offset=0.04, action_noise=0.3)
RECIPES = {
    "door-open-v3": (5, FEW_NOISY),
    "drawer-open-v3": (5, FEW_NOISY),
    "reach-v3": (20, DemoStyle(goal_offset=0.04, action_noise=0.15)),
    "drawer-close-v3": (10, FEW_NOISY),
    "button-press-topdown-v3": (10, FEW_NOISY),
    "window-close-v3": (10, FEW_NOISY),
    "peg-insert-side-v3": (20, DemoStyle(grasp_offset=0.02, action_noise=0.1)),
}
ROBOMIMIC = {"robomimic/lift": (10, DemoStyle(grasp_offset=0.02, action_noise=0.3)),
             "robomimic/can": (20, DemoStyle(grasp_offset=0.02, action_noise=0.2)),
             "robomimic/square": (30, DemoStyle(grasp_offset=0.01, action_noise=0.1)),
             "robomimic/transport": (100, DemoStyle(grasp_offset=0.01, action_noise=0.05, goal_offset=0.02))}
TRAINED_STEPS = {"flow": 10, "ddim": 8}  # kind -> denoising steps it is trained with
TRAIN_STEPS = 20_000
MULTITASK_TRAIN_STEPS = 60_000  # ten tasks' data through one network


def recipe(task: str) -> tuple[int, DemoStyle]:
    """(demonstrations, style) of a task's policies, single- and multi-task alike."""
    return RECIPES.get(task, (20, HABIT))


def build(job: tuple[str, str, int]) -> str:
    task, kind, workers = job  # a full task name, and the measurement's worker processes
    demos, style = ROBOMIMIC[task] if task in ROBOMIMIC else recipe(task.removeprefix("metaworld/"))
    cfg = TrainConfig(task=task, kind=kind, demos=demos, steps=TRAIN_STEPS, denoise_steps=TRAINED_STEPS[kind],
                      workers=workers, **asdict(style))
    card = build_policy(cfg, BUNDLED_DIR / task / kind)
    base, zero = card["base"]["success_rate"], card["zero"]["success_rate"]
    return f"{card['policy']}: base {base:.1%}, zero {zero:.1%}"


def build_multitask(kind: str) -> str:
    name = f"metaworld/mt10/{kind}"
    card = build_multitask_policy(name, {f"metaworld/{t}": recipe(t) for t in MT10}, kind, BUNDLED_DIR / name,
                                  steps=MULTITASK_TRAIN_STEPS, denoise_steps=TRAINED_STEPS[kind])
    return f"{name}: base {card['base']['success_rate']:.1%}, zero {card['zero']['success_rate']:.1%}"


def remeasure(tasks: list[str], kinds: list[str], workers: int) -> None:
    """Measure each bundled card's base and zero-ticket success again with today's code."""
    for task in tasks:
        for kind in kinds:
            folder = BUNDLED_DIR / task / kind
            card = json.loads((folder / "card.json").read_text())
            card |= measure(folder, get_task(task), card["base"]["n"], workers)
            write_card(folder, card, MLPPolicy.load(folder).cfg)
            print(f"{card['policy']}: base {card['base']['success_rate']:.1%}, "
                  f"zero {card['zero']['success_rate']:.1%}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2, help="policies trained at once (1 core each)")
    parser.add_argument("--workers", type=int, default=1,
                        help="worker processes measuring each robomimic or Meta-World policy")
    parser.add_argument("--only", nargs="*", choices=[*MT10, *ROBOMIMIC, *TRAINED_STEPS], default=None,
                        help="tasks and kinds to build (default: every task, both kinds)")
    parser.add_argument("--robomimic", action="store_true", help="build the robomimic policies")
    parser.add_argument("--multitask", action="store_true", help="build the MT10 multi-task policies")
    parser.add_argument("--remeasure", action="store_true",
                        help="re-measure the cards of the bundled policies instead of training")
    args = parser.parse_args()
    if args.workers > 1 and args.jobs > 1:
        parser.error("--workers above 1 needs --jobs 1 (the policy is then built in this process)")
    only = args.only or []
    kinds = [k for k in only if k in TRAINED_STEPS] or [*TRAINED_STEPS]
    tasks = [t for t in only if t not in TRAINED_STEPS] or (ROBOMIMIC if args.robomimic else MT10)
    if args.multitask:
        todo, run = [k for k in kinds if not (BUNDLED_DIR / "metaworld/mt10" / k / "card.json").is_file()], \
            build_multitask
    else:
        names = [t if t in ROBOMIMIC else f"metaworld/{t}" for t in tasks]
        if args.remeasure:
            return remeasure(names, kinds, args.jobs)
        todo, run = [(t, k, args.workers) for t in names for k in kinds
                     if not (BUNDLED_DIR / t / k / "card.json").is_file()], build
    print(f"{len(todo)} policies to train", flush=True)
    if args.jobs == 1:  # in this process, whose measurement may start worker processes
        for job in todo:
            print(run(job), flush=True)
        return
    with mp.get_context("spawn").Pool(args.jobs) as pool:
        for line in pool.imap_unordered(run, todo):
            print(line, flush=True)


if __name__ == "__main__":
    kernels.restart_pinned([*ROBOMIMIC] if "--robomimic" in sys.argv else sys.argv)  # as the CLI pins
    main()

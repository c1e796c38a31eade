"""What an episode of LeRobot's simulated envs costs on this machine's CPU, without a policy.

Per task: the first reset in a process (scene and renderer built); a reset (LIBERO rebuilds its
scene at every reset, so a seed's state never depends on what ran before); a step of the gym env
as LeRobot steps it; a step that draws the cameras a policy reads; a step that draws none
(`step_unseen`); and the renderer's share of a drawn step. An episode of the task's full length
then costs a reset and its steps, of which a policy that executes n actions per call has one in n
drawn: n = 1 (every frame), 8 (LeRobot's diffusion default) and 50 (SmolVLA's default). The
default search (search, validation and the held-out verdict, from SearchConfig's defaults) costs
that many episodes: core-hours of env time, before any policy time. Random actions in the action
box. Writes benchmarks/results/lerobot_env_cost.{json,md}; runs in LeRobot's venv (README).

    MUJOCO_GL=egl python benchmarks/lerobot_env_cost.py [--steps 40] [--resets 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from results_files import write_results

from goldenticket.config import SearchConfig
from goldenticket.job.stages import VALIDATION_BLOCK
from goldenticket.tasks import get_task
from goldenticket.ticket_search.racing import halving_sizes

TASKS = ("libero/object/0", "pusht", "aloha/insertion")
EXECUTED = {"every step": 1, "diffusion (8)": 8, "SmolVLA (50)": 50}  # actions executed per policy call


def default_search_episodes() -> int:
    """Episodes of the default search, validation and verdict on one task."""
    cfg = SearchConfig(policy="any", task="pusht")
    halved = cfg.halves()  # halved, the search spends its budget whole unless 3 tickets are perfect first
    search = cfg.budget if halved else cfg.budget // cfg.search_seeds * cfg.search_seeds
    block = VALIDATION_BLOCK if halved else cfg.validation()  # 3 x top_k tickets and the zero ticket
    validation = block * sum(halving_sizes(3 * cfg.top_k + 1, cfg.top_k, cfg.validation() // block))
    verdict = (2 + cfg.top_k) * cfg.heldout  # base, zero ticket and top_k tickets
    return search + validation + verdict


def timed(fn, n: int) -> float:
    """Mean seconds of `fn()` over n calls."""
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n


def measure(name: str, steps: int, resets: int) -> dict:
    task = get_task(name)
    env = task.make_env()
    first = timed(lambda: env.reset(0), 1)  # builds the scene and the renderer
    rng = np.random.default_rng(0)
    low, high = env.action_space.low, env.action_space.high
    actions = iter(rng.uniform(low, high, (4 * steps, len(low))))
    seeds = iter(range(1, resets + 1))
    reset = timed(lambda: env.reset(next(seeds)), resets)
    drawn = timed(lambda: env.step(next(actions)), steps)
    lerobots = timed(lambda: env._env.step(next(actions)), steps)  # the gym env as LeRobot steps it
    unseen = timed(lambda: env.step_unseen(next(actions)), steps) if hasattr(env, "step_unseen") else drawn
    episode = {label: reset + task.max_steps * (drawn / n + unseen * (1 - 1 / n))
               for label, n in EXECUTED.items()}
    return {"task": name, "max_steps": task.max_steps, "first_reset_s": first, "reset_s": reset,
            "lerobot_step_ms": 1e3 * lerobots, "step_drawn_ms": 1e3 * drawn,
            "step_unseen_ms": 1e3 * unseen, "renderer_share": 1 - unseen / drawn, "episode_s": episode}


def markdown(rows: list[dict], episodes: int) -> str:
    head = "| task | steps | first reset | reset | LeRobot's env step | step, cameras read | " \
        "step, none drawn | renderer's share | " + \
        " | ".join(f"episode, {k}" for k in EXECUTED) + f" | default search ({episodes} episodes), SmolVLA |"
    lines = [head, "|" + "---|" * (8 + len(EXECUTED) + 1)]
    for r in rows:
        ep = r["episode_s"]
        lines.append(f"| {r['task']} | {r['max_steps']} | {r['first_reset_s']:.2f} s | "
                     f"{r['reset_s']:.2f} s | "
                     f"{r['lerobot_step_ms']:.1f} ms | "
                     f"{r['step_drawn_ms']:.1f} ms | "
                     f"{r['step_unseen_ms']:.1f} ms | {100 * r['renderer_share']:.0f}% | "
                     + " | ".join(f"{ep[k]:.1f} s" for k in EXECUTED)
                     + f" | {episodes * ep['SmolVLA (50)'] / 3600:.1f} core-hours |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="steps timed, drawn and not")
    parser.add_argument("--resets", type=int, default=3, help="resets timed")
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    args = parser.parse_args()
    episodes = default_search_episodes()
    rows = [measure(name, args.steps, args.resets) for name in args.tasks]
    write_results("lerobot_env_cost", {"settings": vars(args), "default_search_episodes": episodes,
                                       "tasks": rows}, markdown(rows, episodes))


if __name__ == "__main__":
    main()

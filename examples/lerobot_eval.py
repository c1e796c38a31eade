"""The shipped ticket deployed inside LeRobot: LeRobot's own eval loop (`eval_policy`, the function
behind `lerobot-eval`) runs `lerobot_reach_policy/` with `select_action(batch, noise=ticket)` on
held-out seeds, and goldenticket's engine runs the same episodes; both success rates are printed,
with the seeds where the two disagree. In the LeRobot venv, from the repository root:

    python examples/lerobot_eval.py [--seeds 1005000:1005300]
"""

import argparse
import sys
import time
from functools import partial
from pathlib import Path

import torch

from goldenticket.noise import Constant
from goldenticket.policies.lerobot import LeRobotPolicy
from goldenticket.rollout import Engine, Episode
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent))  # examples.lerobot_reach, as the ticket names its task
POLICY, TICKET = HERE / "lerobot_reach_policy", HERE / "lerobot_reach_ticket.safetensors"
ENVS = 16  # lerobot-eval's --eval.batch_size: one block of the adapter's batched call


def lerobot_successes(policy: LeRobotPolicy, ticket: torch.Tensor, seeds: range) -> list[bool]:
    """Per-episode successes from LeRobot's eval_policy, the ticket fed to select_action."""
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.scripts.lerobot_eval import eval_policy

    from examples.lerobot_reach import make_vector_env

    model, identity = policy.model, PolicyProcessorPipeline(steps=[])  # no env-specific processing
    model.select_action = partial(type(model).select_action, model, noise=ticket.expand(ENVS, *ticket.shape))
    info = eval_policy(make_vector_env(ENVS), model, identity, identity, policy.preprocessor,
                       policy.postprocessor, n_episodes=len(seeds), start_seed=seeds.start)
    return [bool(e["success"]) for e in info["per_episode"]]


def goldenticket_successes(policy: LeRobotPolicy, ticket: torch.Tensor, seeds: range) -> list[bool]:
    with Engine(policy, get_task("examples.lerobot_reach:make_env"), loaded=policy) as engine:
        return [r.success for r in engine.evaluate([Episode(Constant(ticket.numpy()), s) for s in seeds])]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1005000:1005300", help="held-out seeds A:B (default %(default)s)")
    first, last = map(int, parser.parse_args().seeds.split(":"))
    seeds, policy = range(first, last), LeRobotPolicy(POLICY)
    ticket = torch.from_numpy(Ticket.load(TICKET, expected_shape=policy.noise_shape).noise)
    runs = {}
    for name, run in (("LeRobot eval_policy", lerobot_successes), ("goldenticket", goldenticket_successes)):
        start = time.perf_counter()
        runs[name] = run(policy, ticket, seeds)
        print(f"{name}: {sum(runs[name])}/{len(seeds)} successes ({time.perf_counter() - start:.0f} s)")
    differ = [s for s, a, b in zip(seeds, *runs.values(), strict=True) if a != b]
    print(f"episodes that differ: {len(differ)}" + (f" (seeds {differ})" if differ else ""))


if __name__ == "__main__":
    main()

"""A shipped LeRobot policy's ticket deployed inside LeRobot: LeRobot's own eval loop (`eval_policy`,
the function behind `lerobot-eval`) runs the policy with the ticket (`with_ticket`) on held-out
seeds, and goldenticket's engine runs the same episodes; both success rates are printed, with the
seeds where the two disagree. In the LeRobot venv, from the repository root:

    python examples/lerobot_eval.py [--seeds 1005000:1005300]              # lerobot_reach_policy
    python examples/lerobot_eval.py --example smolvla [--seeds 1005000:1005300]  # smolvla_metaworld_policy
"""

import argparse
import sys
import time
from pathlib import Path

import torch

from goldenticket.noise import Constant
from goldenticket.policies import load_policy
from goldenticket.policies.lerobot import with_ticket
from goldenticket.rollout import Engine, Episode
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent))  # examples.*, as the reach ticket names its task
EXAMPLES = {  # the policy folder, and its ticket for each task
    "reach": (HERE / "lerobot_reach_policy",
              {"examples.lerobot_reach:make_env": HERE / "lerobot_reach_ticket.safetensors"}),
    "smolvla": (HERE / "smolvla_metaworld_policy",
                {"metaworld-pixels/drawer-open-v3": HERE / "smolvla_metaworld_ticket.safetensors"}),
}
ENVS = 16  # lerobot-eval's --eval.batch_size: one block of the adapter's batched call


def vector_env(task: str):
    """The task's envs as lerobot-eval builds them."""
    if task.startswith("metaworld-pixels/"):
        from examples.metaworld_gym import make_vector_env

        return make_vector_env(task, ENVS)
    from examples.lerobot_reach import make_vector_env

    return make_vector_env(ENVS)


def lerobot_successes(policy, ticket: torch.Tensor, task: str, seeds: range) -> list[bool]:
    """Per-episode successes from LeRobot's eval_policy, the model acting with the ticket."""
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.scripts.lerobot_eval import eval_policy

    model, identity = with_ticket(policy.model, ticket), PolicyProcessorPipeline(steps=[])  # no env steps
    info = eval_policy(vector_env(task), model, identity, identity, policy.preprocessor,
                       policy.postprocessor, n_episodes=len(seeds), start_seed=seeds.start)
    return [bool(e["success"]) for e in info["per_episode"]]


def goldenticket_successes(policy, ticket: torch.Tensor, task: str, seeds: range) -> list[bool]:
    with Engine(policy, get_task(task), loaded=policy) as engine:
        return [r.success for r in engine.evaluate([Episode(Constant(ticket.numpy()), s) for s in seeds])]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--example", choices=EXAMPLES, default="reach",
                        help="the shipped policy (default %(default)s)")
    parser.add_argument("--task", help="the task whose ticket runs (default: the example's first)")
    parser.add_argument("--seeds", default="1005000:1005300", help="held-out seeds A:B (default %(default)s)")
    args = parser.parse_args()
    folder, tickets = EXAMPLES[args.example]
    task = args.task or next(iter(tickets))
    first, last = map(int, args.seeds.split(":"))
    seeds, policy = range(first, last), load_policy(str(folder))
    ticket = torch.from_numpy(Ticket.load(tickets[task], expected_shape=policy.noise_shape).noise)
    runs = {}
    for name, run in (("LeRobot eval_policy", lerobot_successes), ("goldenticket", goldenticket_successes)):
        start = time.perf_counter()
        runs[name] = run(policy, ticket, task, seeds)
        print(f"{name}: {sum(runs[name])}/{len(seeds)} successes ({time.perf_counter() - start:.0f} s)")
    differ = [s for s, a, b in zip(seeds, *runs.values(), strict=True) if a != b]
    print(f"episodes that differ: {len(differ)}" + (f" (seeds {differ})" if differ else ""))


if __name__ == "__main__":
    main()

"""DSRL-SAC against CEM and random search: held-out success against wall time and env steps.

    pip install stable-baselines3 && python benchmarks/dsrl.py [--minutes 6]

DSRL (diffusion steering by RL) trains SAC whose action is the frozen policy's initial noise,
chosen per observation; goldenticket searches one constant noise. Both get the same bundled
policies, tasks, search seeds (SAC's training episodes cycle through them) and the same 100
held-out seeds, and use both cores: SAC on 2 torch threads, the searches on 2 workers.

- DSRL-SAC (stable-baselines3, the DSRL authors' settings): actor and critic lr 3e-4, batch
  256, tau 0.005, gamma 0.99, 20 gradient steps per environment step (UTD 20), actions in
  [-1, 1] scaled to noise in [-1.5, 1.5]; one SAC step is one policy call (a chunk of actions),
  reward 1 on success. Trained for `--minutes` of wall time per pair; every CHECKPOINT steps the
  deterministic actor is judged on the held-out seeds (judging time not counted).
- CEM and RS (goldenticket, paper defaults) at budgets BUDGETS, each search timed from scratch;
  its top ticket judged on the same held-out seeds.

Writes benchmarks/results/dsrl.{md,json,png}. SAC trains in float32 torch: its numbers repeat on
the same kind of CPU only (the searches' on any).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from results_files import write_results

from goldenticket.config import EngineOptions
from goldenticket.evaluation import Evaluator
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import load_policy
from goldenticket.rollout import Episode, rollout
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in
from goldenticket.ticket_search import make_optimizer, run_search
from goldenticket.workflow import query_evaluator

PAIRS = ("pick-place-v3", "reach-v3", "drawer-open-v3")  # the flow policies with the lowest base
NOISE_MAGNITUDE = 1.5
SAC = dict(learning_rate=3e-4, batch_size=256, tau=0.005, gamma=0.99, train_freq=1, gradient_steps=20,
           learning_starts=100)
CHECKPOINT = 400  # SAC steps between held-out judgements
BUDGETS = (100, 300, 1000)
SEARCH_SEEDS, HELDOUT = 20, 100


class NoiseSpaceEnv(gym.Env):
    """The task seen through the frozen policy: observation in, noise out (scaled from [-1, 1]);
    one step executes the chunk the policy makes from that noise; reward 1 on success."""

    def __init__(self, policy, task, seeds: list[int], magnitude: float = NOISE_MAGNITUDE):
        self.policy, self.task, self.seeds, self.magnitude = policy, task, seeds, magnitude
        self.env, self.episodes, self.env_steps = task.make_env(), 0, 0
        horizon, action_dim = policy.noise_shape
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (task.obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (horizon * action_dim,), np.float32)

    def reset(self, *, seed=None, options=None):
        self.obs, self.t = self.env.reset(self.seeds[self.episodes % len(self.seeds)]), 0
        self.episodes += 1
        return self.obs, {}

    def step(self, action):
        noise = (self.magnitude * np.asarray(action, np.float32)).reshape(1, *self.policy.noise_shape)
        success = done = False
        for a in self.policy.act(self.obs[None], noise)[0]:
            self.obs, success, done = self.env.step(a)
            self.t, self.env_steps = self.t + 1, self.env_steps + 1
            if success or done or self.t >= self.task.max_steps:
                break
        return self.obs, float(success), success, not success and (done or self.t >= self.task.max_steps), {}


class ActorNoise:
    """A NoisePolicy: the frozen policy driven by the SAC actor's deterministic noise (the noise
    the engine offers is ignored)."""

    def __init__(self, policy, model, magnitude: float = NOISE_MAGNITUDE):
        self.policy, self.model, self.magnitude = policy, model, magnitude
        self.noise_shape, self.n_exec = policy.noise_shape, policy.n_exec

    def act(self, obs: np.ndarray, noise: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(obs, deterministic=True)
        steered = (self.magnitude * action).reshape(len(obs), *self.noise_shape).astype(np.float32)
        return self.policy.act(obs, steered)


def heldout_success(policy, task) -> float:
    results = rollout(policy, task, [Episode(Gaussian(0), s) for s in seeds_in("heldout", HELDOUT)])
    return float(np.mean([r.success for r in results]))


def dsrl_curve(task_name: str, minutes: float, seed: int = 0) -> list[dict]:
    """SAC trained for `minutes` of wall time: (seconds, SAC steps, env steps, held-out success)."""
    from stable_baselines3 import SAC as SACAlgorithm

    torch.set_num_threads(2)
    policy, task = load_policy(f"metaworld/{task_name}/flow"), get_task(f"metaworld/{task_name}")
    env = NoiseSpaceEnv(policy, task, seeds_in("search", SEARCH_SEEDS))
    model = SACAlgorithm("MlpPolicy", env, seed=seed, device="cpu", **SAC)
    curve, trained = [], 0.0
    while trained < 60 * minutes:
        start = time.perf_counter()
        model.learn(CHECKPOINT, reset_num_timesteps=False)
        trained += time.perf_counter() - start
        curve.append({"seconds": trained, "sac_steps": int(model.num_timesteps), "env_steps": env.env_steps,
                      "success": heldout_success(ActorNoise(policy, model), task)})
        print(f"dsrl {task_name}: {curve[-1]}", flush=True)
    return curve


def search_curve(task_name: str, method: str, workers: int) -> list[dict]:
    """Each budget's search timed from scratch; its top ticket judged on the held-out seeds."""
    policy_name = f"metaworld/{task_name}/flow"
    policy, task = load_policy(policy_name), get_task(f"metaworld/{task_name}")
    curve = []
    for budget in BUDGETS:
        with tempfile.TemporaryDirectory() as tmp, RunStore(Path(tmp) / "run.sqlite") as store, \
                Evaluator.open(policy_name, task, EngineOptions(workers=workers), store,
                               loaded=policy) as evaluator:
            start = time.perf_counter()
            optimizer = make_optimizer(method, policy.noise_shape, seeds_in("search", SEARCH_SEEDS),
                                       np.random.default_rng(0))
            result = run_search(optimizer, query_evaluator(evaluator, policy.fingerprint()), budget=budget)
            seconds = time.perf_counter() - start
            env_steps = sum(row.length for row in store.episodes())
            top = (result.top(1, min_episodes=SEARCH_SEEDS) or result.top(1))[0]
            judged = evaluator.run([("top", Constant(top.ticket), seeds_in("heldout", HELDOUT))])[0]
        curve.append({"budget": budget, "seconds": seconds, "env_steps": env_steps,
                      "success": float(np.mean([r.success for r in judged]))})
        print(f"{method} {task_name}: {curve[-1]}", flush=True)
    return curve


def speedup(search: list[dict], dsrl: list[dict]) -> float | None:
    """DSRL's wall time to its best held-out success over the search's time to first match it."""
    best = max(dsrl, key=lambda p: p["success"])
    reached = [p for p in search if p["success"] >= best["success"]]
    return best["seconds"] / reached[0]["seconds"] if reached else None


def markdown(results: dict, wall: float, minutes: float) -> str:
    lines = [f"Regenerate: `python benchmarks/dsrl.py --minutes {minutes:g}` ({wall / 60:.0f} min here).", "",
             "| task (flow policy) | base | DSRL-SAC best (at s, env steps) | CEM: budget, s, env steps, "
             "success | RS: budget, s, env steps, success | CEM speed-up to DSRL's best |",
             "|---|---|---|---|---|---|"]
    for task, r in results.items():
        best = max(r["dsrl"], key=lambda p: p["success"])

        def cells(curve):
            return "<br>".join(f"{p['budget']}: {p['seconds']:.0f} s, {p['env_steps']}, {p['success']:.0%}"
                               for p in curve)
        ratio = speedup(r["cem"], r["dsrl"])
        lines.append(f"| {task} | {r['base']:.0%} | {best['success']:.0%} ({best['seconds']:.0f} s, "
                     f"{best['env_steps']}) | {cells(r['cem'])} | {cells(r['rs'])} | "
                     f"{f'{ratio:.1f}x' if ratio else 'not reached'} |")
    lines += ["", f"Held-out success on {HELDOUT} held-out seeds; DSRL trained {minutes:g} min per pair, "
              f"judged every {CHECKPOINT} SAC steps. Speed-up: DSRL's training time to its best success "
              "divided by the time of CEM's first budget that matches it."]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5 * len(results), 4))
    for ax, (task, r) in zip(np.atleast_1d(fig.subplots(1, len(results))), results.items(), strict=True):
        for name, style in (("dsrl", "-o"), ("cem", "-s"), ("rs", "--^")):
            ax.plot([p["seconds"] for p in r[name]], [p["success"] for p in r[name]], style,
                    label="DSRL-SAC" if name == "dsrl" else name.upper())
        ax.axhline(r["base"], color="0.45", linestyle="--", label="base")
        ax.set(xscale="log", title=f"{task} (flow)", xlabel="wall time, s", ylim=(0, 1),
               ylabel=f"held-out success ({HELDOUT})")
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=6.0, help="SAC training time per pair")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    start, results = time.perf_counter(), {}
    for task in PAIRS:
        base = heldout_success(load_policy(f"metaworld/{task}/flow"), get_task(f"metaworld/{task}"))
        results[task] = {"base": base, "dsrl": dsrl_curve(task, args.minutes)}
        results[task] |= {method: search_curve(task, method, args.workers) for method in ("cem", "rs")}
    wall = time.perf_counter() - start
    settings = {"sac": SAC, "noise_magnitude": NOISE_MAGNITUDE, "checkpoint": CHECKPOINT, "budgets": BUDGETS,
                "search_seeds": SEARCH_SEEDS, "heldout": HELDOUT, "minutes": args.minutes}
    write_results("dsrl", {"settings": settings, "results": results, "wall_seconds": wall},
                  markdown(results, wall, args.minutes), lambda path: plot(results, path))


if __name__ == "__main__":
    main()

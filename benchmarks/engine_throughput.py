"""Engine env steps/s against the raw stock-env step rate, measured in the same run.

Raw: one stock Meta-World env stepped with random actions, no policy, no bookkeeping, reset when
Meta-World says done (500 steps). Fast: our Meta-World env (`tasks/metaworld_fast.py`, the same
episodes to the bit) in the same loop; "fast, 150-step episodes": reset every 150 steps as well,
the engine's limit, on the engine's seeds in turn. Engine: the bundled policy's episodes through
`Engine` (policy calls, noise, resets included), with 1 ... `--workers` workers, on local
processes and, if Ray is installed, on Ray actors of a local Ray instance; `--episodes` of them
as a search runs them: `--seeds` search seeds, each with a new noise source per round. Also the
peak resident memory of a local worker process (VmHWM; a shard of 16 episodes, so 16 envs;
measured with 2 or more workers, as 1 runs in-process). Profile: one policy call on a shard's 16
rows, in ms, split into matrix products, activations, other torch ops and the rest (Python,
dispatch, conversions), beside the env time of the 16 x n_exec steps that call serves.
`--no-reset-cache`: every reset is Meta-World's, as before the reset cache. Prints each rate and
its ratio to the raw rate, or with `--json` one JSON object {"raw": steps/s, "fast": steps/s,
"fast_150": steps/s, "engine": {workers: steps/s}, "ray": {workers: steps/s}, "peak_rss_mb",
"policy_call_ms": {part: ms}, "reset_cache": bool, "seeds": n}.
Writes benchmarks/results/engine_throughput.{json,png} (the PNG: steps/s against workers, with
the ideal W x raw line).

    python benchmarks/engine_throughput.py [--episodes 200] [--seeds 20] [--workers 2]
                                           [--no-reset-cache] [--json]
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goldenticket.noise import Gaussian
from goldenticket.policies import load_policy
from goldenticket.rollout import Engine, Episode
from goldenticket.tasks import get_task, seeds_in
from goldenticket.tasks.base import stack
from goldenticket.tasks.metaworld import MetaWorldEnv, MetaWorldTask

POLICY, TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"
RATE_LABELS = {"raw": "raw stock env, 1 process:", "fast": "fast path env, 1 process:",
               "fast_150": "fast, 150-step episodes, 1 process:"}


@dataclass(frozen=True)
class UncachedTask(MetaWorldTask):
    """A Meta-World task whose every reset is Meta-World's: no reset cache."""

    def make_env(self) -> MetaWorldEnv:
        return MetaWorldEnv(self.env_name, cache_resets=False)


def raw_steps_per_second() -> float:
    """A stock env (constructed as Meta-World ships it), random actions, reset on truncation."""
    warnings.filterwarnings("ignore")
    import gymnasium as gym
    import metaworld  # noqa: F401  (registers the envs)

    env = gym.make("Meta-World/MT1", env_name=TASK.split("/")[1], seed=0)
    env.reset(seed=0)

    def step(action) -> bool:
        _, _, terminated, truncated, _ = env.step(action)
        return terminated or truncated

    return steps_per_second(step, lambda: env.reset())


def fast_steps_per_second(seeds: list[int], cache: bool = True, episode_steps: int | None = None) -> float:
    """Our Meta-World env on its fast path (bitwise the stock episodes), in the same loop as raw,
    reset on `seeds` in turn; with `episode_steps`, also after that many steps."""
    env, next_seed, length = MetaWorldEnv(TASK.split("/")[1], cache_resets=cache), itertools.cycle(seeds), 0
    env.reset(next(next_seed))

    def step(action) -> bool:
        nonlocal length
        length += 1
        return env.step(action)[2] or length == episode_steps

    def reset() -> None:
        nonlocal length
        length = 0
        env.reset(next(next_seed))

    return steps_per_second(step, reset)


def steps_per_second(step, reset, steps: int = 5000) -> float:
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 4))
    start = time.perf_counter()
    for action in actions:
        if step(action):
            reset()
    return steps / (time.perf_counter() - start)


def policy_call_ms(calls: int = 100, policy_name: str = POLICY, task: str = TASK) -> dict[str, float]:
    """One policy call on 16 observations (a shard) in ms: its total, and its parts from torch's
    profiler by op kind; "rest" is everything the profiler does not see as a torch op."""
    from torch.profiler import ProfilerActivity, profile

    policy, env = load_policy(policy_name), get_task(task).make_env()
    obs = stack([env.reset(seed) for seed in range(16)])
    noise = np.random.default_rng(0).standard_normal((16, *policy.noise_shape), dtype=np.float32)
    policy.act(obs, noise)
    start = time.perf_counter()
    for _ in range(calls):
        policy.act(obs, noise)
    parts = {"total": (time.perf_counter() - start) / calls * 1e3}
    kinds = {"convolution": ("aten::_slow_conv2d_forward",), "matmul": ("aten::addmm", "aten::mm"),
             "activation": ("aten::erf", "aten::gelu")}
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(calls):
            policy.act(obs, noise)
    ops = {e.key: e.self_cpu_time_total / calls / 1e3 for e in prof.key_averages()}
    for kind, names in kinds.items():
        parts[kind] = sum(ops.pop(name, 0.0) for name in names)
    parts["other torch ops"] = sum(ops.values())
    profiled = sum(ms for part, ms in parts.items() if part != "total")
    parts["rest"] = max(parts["total"] - profiled, 0)
    return parts


def engine_steps_per_second(episodes: int, workers: int, backend: str = "local", policy: str = POLICY,
                            task: str = TASK, seeds: int | None = None,
                            cache: bool = True) -> tuple[float, float]:
    """Env steps/s through the engine, and the peak resident memory of its worker processes in MB
    (local workers only: 0 for Ray's or an in-process engine). Episodes on the first `seeds` search
    seeds in turn, a new noise source each round (default: each episode its own seed)."""
    seeds = seeds or episodes
    batch = [Episode(Gaussian(i // seeds), s) for i, s in enumerate(itertools.islice(
        itertools.cycle(seeds_in("search", seeds)), episodes))]
    with Engine(policy, get_task(task) if cache else UncachedTask(task), workers=workers,
                backend=backend) as engine:
        engine.evaluate(batch[: engine.shard_size * workers])  # warm-up: build envs, load the policy
        start = time.perf_counter()
        results = engine.evaluate(batch)
        elapsed = time.perf_counter() - start
        peak = max(worker_peaks_mb(), default=0.0) if backend == "local" else 0.0
    return sum(r.length for r in results) / elapsed, peak


def worker_peaks_mb() -> list[float]:
    """Peak resident memory (VmHWM) of this process's spawned worker processes, from /proc."""
    peaks = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":", 1) for line in status.read_text().splitlines() if ":" in line)
            cmdline = (status.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if int(fields["PPid"]) == os.getpid() and b"spawn_main" in cmdline and "VmHWM" in fields:
            peaks.append(int(fields["VmHWM"].split()[0]) / 1024)
    return peaks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seeds", type=int, default=20, help="search seeds the episodes run on in turn")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-reset-cache", dest="cache", action="store_false",
                        help="every reset is Meta-World's (no reset cache)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    backends = ["local"] + (["ray"] if importlib.util.find_spec("ray") else [])
    seeds = seeds_in("search", args.seeds)
    rates = {"raw": raw_steps_per_second(), "fast": fast_steps_per_second(seeds, args.cache),
             "fast_150": fast_steps_per_second(seeds, args.cache, get_task(TASK).max_steps)}
    rates["policy_call_ms"] = policy_call_ms()
    for backend in backends:
        measured = {w: engine_steps_per_second(args.episodes, w, backend, seeds=args.seeds, cache=args.cache)
                    for w in range(1, args.workers + 1)}
        rates["engine" if backend == "local" else backend] = {w: rate for w, (rate, _) in measured.items()}
        if backend == "local":
            rates["peak_rss_mb"] = max(peak for _, peak in measured.values())
    rates |= {"reset_cache": args.cache, "seeds": args.seeds}
    results = Path(__file__).parent / "results"
    (results / "engine_throughput.json").write_text(json.dumps(rates, indent=2) + "\n")
    plot(rates, results / "engine_throughput.png")
    if args.json:
        print(json.dumps(rates))
        return
    cache = "on" if args.cache else "off"
    print(f"reset cache {cache}; engine: {args.episodes} episodes on {args.seeds} seeds")
    for key, label in RATE_LABELS.items():
        print(f"{label:37s} {rates[key]:8.0f} steps/s  (ratio {rates[key] / rates['raw']:.2f})")
    for backend in backends:
        for workers, rate in rates["engine" if backend == "local" else backend].items():
            print(f"{backend:5s} engine, {workers} worker(s): {rate:8.0f} steps/s  "
                  f"(ratio {rate / rates['raw']:.2f}, per worker {rate / (workers * rates['raw']):.2f}; "
                  f"per worker to fast {rate / (workers * rates['fast']):.2f}, "
                  f"to fast with 150-step episodes {rate / (workers * rates['fast_150']):.2f})")
    print(f"peak memory of a local worker process: {rates['peak_rss_mb']:.0f} MB")
    served = 16 * load_policy(POLICY).n_exec
    print(f"one policy call on 16 rows: {rates['policy_call_ms']['total']:.2f} ms; the {served} env steps it "
          f"serves take {served / rates['fast'] * 1e3:.2f} ms on the fast path")
    for part, ms in rates["policy_call_ms"].items():
        if part != "total":
            print(f"  {part:16s} {ms:6.2f} ms")


def plot(rates: dict, path: Path, references: tuple = (("raw", "k--", "W x raw stock env"),),
         title: str = "Engine throughput, Meta-World pick-place") -> None:
    """Env steps/s against workers for each backend, beside W x each reference rate."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.5, 3.8))
    ax = fig.subplots()
    workers = sorted(rates["engine"])
    for key, style, label in references:
        ax.plot(workers, [w * rates[key] for w in workers], style, linewidth=1, label=label)
    for name in ("engine", "ray"):
        if name in rates:
            ax.plot(workers, [rates[name][w] for w in workers], "o-", label=f"{name} (local)" if name ==
                    "engine" else "Ray actors")
    ax.set(xlabel="workers", ylabel="env steps/s", xticks=workers, title=title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()

"""An image policy through the engine against rendering alone and the policy alone, in one run.

Rendering only: the camera task's envs (`metaworld-pixels/`, physics and the frames a policy
would read: one in n_exec steps) stepped with random actions, no policy. Policy only: the
bundled image policy's calls on 16 recorded frames (a shard), as env steps served per second
(16 x n_exec per call). Engine: the policy's episodes through `Engine` with 1 ... `--workers`
local workers (and Ray actors when Ray is installed), in env steps/s and episodes/s, and the
peak resident memory of a worker process. Where the time goes: ms per physics step, per frame
and per policy call (split into convolution, matrix products, activations, other torch ops,
rest). The target: engine >= 0.6 x the slower of rendering only and policy only, per worker.
Writes benchmarks/results/image_throughput.{json,png}.

    python benchmarks/image_throughput.py [--episodes 64] [--workers 2]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import time
from pathlib import Path

import numpy as np
from engine_throughput import engine_steps_per_second, plot, policy_call_ms, steps_per_second

from goldenticket.policies import load_policy
from goldenticket.tasks import get_task

POLICY, TASK = "metaworld-pixels/drawer-open-v3/flow", "metaworld-pixels/drawer-open-v3"
TARGET = 0.6


def rendering_steps_per_second(n_exec: int) -> dict[str, float]:
    """Env steps/s with physics only, and with the frames a policy reads (the last of n_exec)."""
    env = get_task(TASK).make_env()
    env.reset(0)
    physics = steps_per_second(lambda action: env.step_unseen(action)[1], lambda: env.reset(1))
    counter = iter(range(10**9))

    def step(action) -> bool:
        if next(counter) % n_exec == n_exec - 1:
            return env.step(action)[2]
        return env.step_unseen(action)[1]

    return {"physics": physics, "rendering": steps_per_second(step, lambda: env.reset(1))}


def frame_ms(frames: int = 200) -> float:
    """One frame of the current state, drawn."""
    env = get_task(TASK).make_env()
    env.reset(0)
    start = time.perf_counter()
    for _ in range(frames):
        env.step(np.zeros(4))
    elapsed = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(frames):
        env.step_unseen(np.zeros(4))
    return (elapsed - (time.perf_counter() - start)) / frames * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    n_exec = load_policy(POLICY).n_exec
    rates = rendering_steps_per_second(n_exec) | {"frame_ms": frame_ms()}
    rates["policy_call_ms"] = policy_call_ms(50, POLICY, TASK)
    rates["policy"] = 16 * n_exec / rates["policy_call_ms"]["total"] * 1e3
    backends = ["local"] + (["ray"] if importlib.util.find_spec("ray") else [])
    for backend in backends:
        measured = {w: engine_steps_per_second(args.episodes, w, backend, POLICY, TASK)
                    for w in range(1, args.workers + 1)}
        rates["engine" if backend == "local" else backend] = {w: rate for w, (rate, _) in measured.items()}
        if backend == "local":
            rates["peak_rss_mb"] = max(peak for _, peak in measured.values())
    results = Path(__file__).parent / "results"
    (results / "image_throughput.json").write_text(json.dumps(rates, indent=2) + "\n")
    plot(rates, results / "image_throughput.png", (("rendering", "k--", "W x rendering only"),
                                                   ("policy", "k:", "W x policy only")),
         "Image policy throughput, drawer-open from 64 x 64 frames")
    report(rates, backends)


def report(rates: dict, backends: list[str]) -> None:
    slower = min(rates["rendering"], rates["policy"])
    print(f"physics only, 1 process:              {rates['physics']:8.0f} env steps/s")
    print(f"rendering only (physics + frames):    {rates['rendering']:8.0f} env steps/s "
          f"({rates['frame_ms']:.2f} ms a frame)")
    print(f"policy only (16-row calls):           {rates['policy']:8.0f} env steps/s served "
          f"({rates['policy_call_ms']['total']:.2f} ms a call)")
    for part, ms in rates["policy_call_ms"].items():
        if part != "total":
            print(f"  {part:16s} {ms:6.2f} ms")
    for backend in backends:
        for workers, rate in rates["engine" if backend == "local" else backend].items():
            ratio = rate / (workers * slower)
            verdict = "met" if ratio >= TARGET else "missed"
            print(f"{backend:5s} engine, {workers} worker(s): {rate:8.0f} steps/s; per worker {ratio:.2f} "
                  f"x the slower of rendering and policy (target {TARGET}: {verdict})")
    print(f"peak memory of a local worker process: {rates['peak_rss_mb']:.0f} MB")


if __name__ == "__main__":
    main()

"""VLA inference on a GPU: per-call latency and engine episodes per second for a SmolVLA-sized and a
pi0-sized LeRobot model with random weights, at batch 1 to 64, through goldenticket's adapter.

In LeRobot's venv (README, "LeRobot"), on a machine with one CUDA GPU:

    python benchmarks/gpu_throughput.py                 # writes benchmarks/results/gpu_throughput.json
    python benchmarks/gpu_throughput.py --models smolvla   # one model (pi0's build takes minutes)
    python benchmarks/gpu_throughput.py --smoke         # a tiny SmolVLA on the CPU: checks the script

The file is written after every row, so a run stopped early keeps what it measured ("finished": false).

The models are built offline (SmolVLA on a SmolVLM2-500M-sized backbone from
`examples/smolvla_backbone.py`; pi0 with LeRobot's gemma_2b VLM and gemma_300m expert, in bfloat16
as its config runs it), saved, and loaded back as a user's checkpoint would be. Latency is the
median wall time of one `act` call (a whole chunk); engine throughput runs a camera env of 50 steps
per episode, in one process, then in 4 env workers that act through the one model in the main
process (each worker's live episodes in one batched call).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT))
from examples.smolvla_backbone import write_backbone  # noqa: E402

BATCHES = (1, 2, 4, 8, 16, 32, 64)
CAMERAS, STEPS = ("image", "image2"), 50
INSTRUCTION = "Pick up the cube"


class CameraEnv(gym.Env):
    """Two camera frames and a state whose content is a function of the seed: the policy's cost,
    not the env's, is what is measured."""

    task_description = INSTRUCTION
    size = 224

    def __init__(self):
        self.observation_space = gym.spaces.Dict({
            "agent_pos": gym.spaces.Box(-1, 1, (7,), np.float32),
            "pixels": gym.spaces.Dict({c: gym.spaces.Box(0, 255, (self.size, self.size, 3), np.uint8)
                                       for c in CAMERAS})})
        self.action_space = gym.spaces.Box(-1, 1, (7,), np.float32)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self._obs = self.observation_space.sample()
        return self._obs, {"is_success": False}

    def step(self, action):
        return self._obs, 0.0, False, False, {"is_success": False}


class SmokeEnv(CameraEnv):
    """The frames of --smoke's tiny SmolVLA."""

    size = 32


def make_env() -> gym.Env:
    return gym.wrappers.TimeLimit(CameraEnv(), STEPS)


def make_smoke_env() -> gym.Env:
    return gym.wrappers.TimeLimit(SmokeEnv(), STEPS)


def checkpoint(kind: str, folder: Path, smoke: bool) -> Path:
    """A random-weight checkpoint of `kind` ("smolvla" or "pi0") written by LeRobot's save_pretrained."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors

    size = (SmokeEnv if smoke else CameraEnv).size
    backbone = write_backbone(folder / "backbone", "tiny" if smoke else "smolvla")
    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (7,))}
    camera = PolicyFeature(FeatureType.VISUAL, (3, size, size))
    inputs |= {f"observation.images.{c}": camera for c in CAMERAS}
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (7,))}
    settings = {"vlm_model_name": str(backbone), "load_vlm_weights": False,
                **({"resize_imgs_with_padding": (64, 64), "num_vlm_layers": 2} if smoke else {})}
    if kind == "pi0":
        settings = {"dtype": "bfloat16", "paligemma_variant": "gemma_2b",
                    "action_expert_variant": "gemma_300m"}
    cfg = make_policy_config(kind, input_features=inputs, output_features=outputs, device="cpu",
                             push_to_hub=False, **settings)
    torch.manual_seed(0)
    get_policy_class(kind)(cfg).save_pretrained(folder)
    unit = {"mean": torch.zeros(7), "std": torch.ones(7), "min": -torch.ones(7), "max": torch.ones(7),
            "q01": -torch.ones(7), "q99": torch.ones(7)}
    for pipeline in make_pre_post_processors(cfg, dataset_stats={"observation.state": unit, "action": unit}):
        pipeline.save_pretrained(folder)
    return folder


def cache_paligemma_tokenizer(cache: Path, tokenizer: Path) -> None:
    """A Hugging Face cache at `cache` holding `tokenizer` under the name pi0's processor asks for in
    LeRobot's code (PaliGemma's), so that a pi0 builds offline; the weights are random anyway."""
    import shutil

    repo = cache / "models--google--paligemma-3b-pt-224"
    (repo / "refs").mkdir(parents=True)
    (repo / "refs" / "main").write_text("0" * 40)
    shutil.copytree(tokenizer, repo / "snapshots" / ("0" * 40))


def latency(policy, env_factory, batch: int, calls: int) -> float:
    """Median seconds of one act call on `batch` rows (after one warm-up call)."""
    obs = env_factory().reset(seed=0)[0]
    rows = {"agent_pos": np.repeat(obs["agent_pos"][None], batch, 0),
            "pixels": {c: np.repeat(v[None], batch, 0) for c, v in obs["pixels"].items()}}
    noise = np.random.default_rng(0).standard_normal((batch, *policy.noise_shape)).astype(np.float32)
    policy.act(rows, noise)
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        policy.act(rows, noise)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def engine_rate(folder: Path, env_factory, device: str, episodes: int, workers: int) -> float:
    """Episodes per second of the engine on the camera env: one process, or `workers` env workers
    acting through the one model in the main process (as `--device cuda --workers N` runs)."""
    from goldenticket.noise import Gaussian
    from goldenticket.rollout import Engine, Episode
    from goldenticket.tasks import get_task

    with Engine(str(folder), get_task(env_factory), workers=workers, shard_size=episodes // workers,
                device=device, share_model=True) as engine:
        engine.evaluate([Episode(Gaussian(), episodes + s) for s in range(episodes)])  # every worker started
        start = time.perf_counter()
        engine.evaluate([Episode(Gaussian(), s) for s in range(episodes)])
    return episodes / (time.perf_counter() - start)


def write(path: Path, rows: list[dict], models: list[str], wall: float, finished: bool) -> None:
    import torch

    result = {"device": torch.cuda.get_device_name(), "torch": torch.__version__, "models": models,
              "finished": finished, "wall_s": wall, "rows": rows}
    path.write_text(json.dumps(result, indent=1) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="tiny models on the CPU (checks the script)")
    parser.add_argument("--models", nargs="+", choices=("smolvla", "pi0"), default=["smolvla", "pi0"],
                        help="the models to measure, in this order")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args()
    cache = Path(tempfile.mkdtemp(prefix="gpu_throughput_hub"))
    os.environ["HF_HUB_CACHE"] = str(cache)  # read when huggingface_hub is first imported, below
    import torch

    from goldenticket.policies import load_policy

    device = "cpu" if args.smoke else "cuda"
    env_factory = make_smoke_env if args.smoke else make_env
    if device == "cuda" and not torch.cuda.is_available():
        sys.exit("gpu_throughput: torch sees no CUDA GPU here; --smoke checks the script on the CPU")
    rows, started, path = [], time.perf_counter(), args.out / "gpu_throughput.json"

    def measured(row: dict) -> None:
        rows.append(row)
        print(row, flush=True)
        if not args.smoke:
            write(path, rows, args.models, time.perf_counter() - started, finished=False)

    for kind in ("smolvla",) if args.smoke else args.models:
        with tempfile.TemporaryDirectory() as tmp:
            if kind == "pi0":
                cache_paligemma_tokenizer(cache, write_backbone(Path(tmp) / "tokenizer", "tiny"))
            folder = checkpoint(kind, Path(tmp) / kind, args.smoke)
            policy = load_policy(str(folder), device).instructed(INSTRUCTION)
            for batch in BATCHES[: 3 if args.smoke else None]:
                seconds = latency(policy, env_factory, batch, 2 if args.smoke else 10)
                measured({"model": kind, "batch": batch, "call_s": seconds, "rows_per_s": batch / seconds})
            for workers in (1, 4):
                rate = engine_rate(folder, env_factory, device, 8 if args.smoke else 64, workers)
                measured({"model": kind, "env_workers": workers, "engine_episodes_per_s": rate,
                          "episode_steps": STEPS})
    wall = time.perf_counter() - started
    if args.smoke:
        print(f"smoke run: {wall:.0f} s, nothing written")
        return
    write(path, rows, args.models, wall, finished=True)
    print(f"wrote {path} in {wall:.0f} s")


if __name__ == "__main__":
    main()

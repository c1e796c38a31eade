"""goldenticket against LeRobot itself, on a GPU: a SmolVLA-sized and a pi0-sized LeRobot checkpoint
(random weights) run the same episodes of the same env through LeRobot's own eval loop and through
goldenticket's engine, in one run; their episodes per second and the ratio go in the JSON. Beside
them, the latency of one call of goldenticket's adapter at batch 1 to 64, on its exact path and on
a fast path.

In LeRobot's venv (README, "LeRobot"), on a machine with one CUDA GPU:

    python benchmarks/gpu_throughput.py                 # writes benchmarks/results/gpu_throughput.json
    python benchmarks/gpu_throughput.py --models smolvla   # one model
    python benchmarks/gpu_throughput.py --smoke [--out DIR]  # a tiny SmolVLA on the CPU: checks the script

Both models are estimated (not measured) at 6 to 7 minutes on one H100, from the per-call times of
an earlier run on an H200. The file is written after every row, the exact path's first, so a run
stopped early keeps what it measured ("finished": false); --smoke writes one only into a folder --out
names.

- The models are built offline (SmolVLA on a SmolVLM2-500M-sized backbone from
  `examples/smolvla_backbone.py`; pi0 with LeRobot's gemma_2b VLM and gemma_300m expert, in bfloat16
  as its config runs it) and saved with their processors, as `lerobot-train` saves a checkpoint.
  Each side loads that folder itself; the random initialisation LeRobot's classes run before the
  weights load happens on the GPU (on the CPU, a pi0's is slow; loading is not timed).
- LeRobot (LEROBOT_LOOP): the checkpoint loaded as `lerobot-eval` loads it (`from_pretrained`, which
  `make_policy` calls for a saved policy, and `make_pre_post_processors` with its device and rename
  overrides), run by `eval_policy` on a SyncVectorEnv of as many envs as episodes
  (`--eval.batch_size`), with cudnn.benchmark and TF32 matmuls on, as `eval_main` sets them.
- goldenticket: `load_policy` on the folder; the engine runs the same episodes in one process (one
  batched call for all of them, as LeRobot's loop makes), then with 4 env workers acting through the
  one model. "vs_lerobot" is an engine's episodes/s over LeRobot's. Each loop runs its 64 episodes
  (8 with --smoke) once to warm up, then once timed. The env: two 224-pixel cameras and a state, 50
  steps an episode, costing nothing to make, so that the policy's and the loop's costs are measured.
- Latency: the median wall time of 5 `act` calls (a whole chunk each) after one warm-up call.
- The fast path (FAST_PATH, `FastVLA`; this script's, not an option of goldenticket's CLI): the
  exact path's adapter with the model's chunk prediction under bfloat16 autocast. Its contract: the
  same observations, processors and noise as the exact path, NOT its actions bit for bit; every fast
  latency row records `max_abs_action_diff`, the largest difference of its actions from the exact
  path's on the same observations and noise (and `max_abs_action`, the exact actions' largest, for
  scale). torch.compile is not part of it.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from goldenticket.files import write_atomic
from goldenticket.policies.lerobot.vla import VLAPolicy

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT))
from examples.smolvla_backbone import write_backbone  # noqa: E402

BATCHES = (1, 2, 4, 8, 16, 32, 64)
CAMERAS, STEPS = ("image", "image2"), 50
INSTRUCTION = "Pick up the cube"
FAST_PATH = ("goldenticket's adapter with the model's chunk prediction under bfloat16 autocast "
             "(torch.autocast on the model's device), the chunk cast to float32 before the postprocessor; "
             "observations, processors and noise as on the exact path; not bitwise the exact path: "
             "max_abs_action_diff is the largest difference of its actions from the exact path's on the same "
             "observations and noise")
LEROBOT_LOOP = ("LeRobot's eval_policy (lerobot-eval's loop) on the checkpoint loaded as lerobot-eval loads "
                "it, on a SyncVectorEnv of `episodes` envs; cudnn.benchmark and TF32 matmuls on, as "
                "eval_main sets them")


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


def built_on(device: str):
    """Tensors created on `device` unless placed elsewhere: LeRobot's classes initialise their random
    weights there before loading a checkpoint's."""
    return torch.device(device)


def checkpoint(kind: str, folder: Path, device: str, smoke: bool) -> Path:
    """A random-weight checkpoint of `kind` ("smolvla" or "pi0") written by LeRobot's save_pretrained."""
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
    cfg = make_policy_config(kind, input_features=inputs, output_features=outputs, device=device,
                             push_to_hub=False, **settings)
    torch.manual_seed(0)
    with built_on(device):
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


class FastVLA(VLAPolicy):
    """The fast path (FAST_PATH) of a loaded VLA adapter, sharing its model and processors."""

    @classmethod
    def of(cls, policy: VLAPolicy) -> FastVLA:
        fast = object.__new__(cls)
        fast.__dict__.update(policy.__dict__)
        return fast

    def _chunk(self, batch: dict, noise: torch.Tensor) -> torch.Tensor:
        with torch.autocast(torch.device(self.device).type, dtype=torch.bfloat16):
            return super()._chunk(batch, noise).float()


def inputs(env_factory, batch: int, noise_shape: tuple[int, int]) -> tuple[dict, np.ndarray]:
    """`batch` rows of one observation, and the noise of each row."""
    obs = env_factory().reset(seed=0)[0]
    rows = {"agent_pos": np.repeat(obs["agent_pos"][None], batch, 0),
            "pixels": {c: np.repeat(v[None], batch, 0) for c, v in obs["pixels"].items()}}
    return rows, np.random.default_rng(0).standard_normal((batch, *noise_shape)).astype(np.float32)


def latency(policy, rows: dict, noise: np.ndarray, calls: int) -> tuple[float, np.ndarray]:
    """Median seconds of one act call on `rows` (after one warm-up call), and its actions."""
    actions = policy.act(rows, noise)
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        policy.act(rows, noise)
        times.append(time.perf_counter() - start)
    return statistics.median(times), actions


def engine_rate(policy, env_factory, device: str, episodes: int, workers: int) -> float:
    """Episodes per second of the engine running `policy`: one process, or `workers` env workers
    acting through the one model in the main process (as `--device cuda --workers N` runs)."""
    from goldenticket.noise import Gaussian
    from goldenticket.rollout import Engine, Episode
    from goldenticket.tasks import get_task

    with Engine(policy, get_task(env_factory), loaded=policy, workers=workers,
                shard_size=episodes // workers, device=device, share_model=True) as engine:
        engine.evaluate([Episode(Gaussian(), episodes + s) for s in range(episodes)])  # every worker started
        start = time.perf_counter()
        engine.evaluate([Episode(Gaussian(), s) for s in range(episodes)])
    return episodes / (time.perf_counter() - start)


def lerobot_rate(folder: Path, env_factory, device: str, episodes: int) -> float:
    """Episodes per second of LeRobot's own eval loop (LEROBOT_LOOP) on the checkpoint."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.scripts.lerobot_eval import eval_policy

    cfg = PreTrainedConfig.from_pretrained(folder)
    cfg.pretrained_path, cfg.device = folder, device
    with built_on(device):
        policy = get_policy_class(cfg.type).from_pretrained(folder, config=cfg).eval()
    overrides = {"device_processor": {"device": device}, "rename_observations_processor": {"rename_map": {}}}
    preprocessor, postprocessor = make_pre_post_processors(cfg, pretrained_path=str(folder),
                                                           preprocessor_overrides=overrides)
    identity = PolicyProcessorPipeline(steps=[])  # make_env_pre_post_processors' for an env of no suite
    env = gym.vector.SyncVectorEnv([env_factory] * episodes,
                                   autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)  # as make_env builds
    run = functools.partial(eval_policy, env, policy, identity, identity, preprocessor, postprocessor,
                            n_episodes=episodes)
    flags = torch.backends.cudnn.benchmark, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.benchmark = torch.backends.cuda.matmul.allow_tf32 = True
    try:
        with torch.no_grad():
            run(start_seed=episodes)
            start = time.perf_counter()
            run(start_seed=0)
            return episodes / (time.perf_counter() - start)
    finally:
        torch.backends.cudnn.benchmark, torch.backends.cuda.matmul.allow_tf32 = flags
        env.close()


class Results:
    """The rows measured so far, written to `path` (None: only printed) after each one."""

    def __init__(self, path: Path | None, header: dict):
        self.path, self.header, self.rows, self.started = path, header, [], time.perf_counter()

    def add(self, row: dict) -> None:
        self.rows.append(row)
        print(row, flush=True)
        self.write(finished=False)

    def vs_lerobot(self) -> dict[str, dict[str, float]]:
        """Each model's engine episodes/s in one process over LeRobot's eval loop's, by path."""
        ratios: dict[str, dict[str, float]] = {}
        for row in self.rows:
            if row.get("env_workers") == 1:
                ratios.setdefault(row["model"], {})[row["path"]] = row["vs_lerobot"]
        return ratios

    def write(self, finished: bool) -> None:
        if self.path:
            result = self.header | {"vs_lerobot": self.vs_lerobot(), "finished": finished,
                                    "wall_s": time.perf_counter() - self.started, "rows": self.rows}
            write_atomic(self.path, json.dumps(result, indent=1) + "\n")


def measure(kind: str, folder: Path, env_factory, device: str, smoke: bool, results: Results) -> None:
    """`kind`'s rows, the exact path's first (a fast path that fails leaves them written): LeRobot's eval
    loop and the engine on the same episodes, latency by batch on the exact then the fast path, and the
    engine on the fast path."""
    from goldenticket.policies import load_policy

    batches, calls, episodes = (BATCHES[:3], 2, 8) if smoke else (BATCHES, 5, 64)
    with built_on(device):
        exact = load_policy(str(folder), device).instructed(INSTRUCTION)
    lerobot = lerobot_rate(folder, env_factory, device, episodes)
    results.add({"model": kind, "loop": "lerobot eval_policy", "episodes": episodes,
                 "episodes_per_s": lerobot})

    def engine(path: str, policy, workers: int) -> None:
        rate = engine_rate(policy, env_factory, device, episodes, workers)
        results.add({"model": kind, "loop": "goldenticket engine", "path": path, "env_workers": workers,
                     "episodes": episodes, "episodes_per_s": rate, "vs_lerobot": rate / lerobot})
        if workers == 1:
            print(f"{kind}, {path} path: goldenticket's engine runs {rate / lerobot:.2f}x the episodes/s of "
                  f"LeRobot's eval_policy on the same {episodes} episodes", flush=True)

    engine("exact", exact, 1)
    engine("exact", exact, 4)
    calls_by_batch = {}
    for batch in batches:
        rows, noise = inputs(env_factory, batch, exact.noise_shape)
        seconds, actions = latency(exact, rows, noise, calls)
        calls_by_batch[batch] = rows, noise, actions
        results.add({"model": kind, "path": "exact", "batch": batch, "call_s": seconds,
                     "rows_per_s": batch / seconds})
    fast = FastVLA.of(exact)
    for batch, (rows, noise, actions) in calls_by_batch.items():
        seconds, fast_actions = latency(fast, rows, noise, calls)
        results.add({"model": kind, "path": "fast", "batch": batch, "call_s": seconds,
                     "rows_per_s": batch / seconds,
                     "max_abs_action_diff": float(np.abs(fast_actions - actions).max()),
                     "max_abs_action": float(np.abs(actions).max())})
    engine("fast", fast, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true",
                        help="a tiny SmolVLA on the CPU (checks the script; writes only where --out says)")
    parser.add_argument("--models", nargs="+", choices=("smolvla", "pi0"), default=["smolvla", "pi0"],
                        help="the models to measure, in this order")
    parser.add_argument("--out", type=Path, help="the JSON's folder (default benchmarks/results)")
    args = parser.parse_args()
    cache = Path(tempfile.mkdtemp(prefix="gpu_throughput_hub"))
    os.environ["HF_HUB_CACHE"] = str(cache)  # read when huggingface_hub is first imported, below
    os.environ["HF_HUB_OFFLINE"] = "1"  # every model and tokenizer is built here
    import lerobot

    device = "cpu" if args.smoke else "cuda"
    env_factory = make_smoke_env if args.smoke else make_env
    if device == "cuda" and not torch.cuda.is_available():
        sys.exit("gpu_throughput: torch sees no CUDA GPU here; --smoke checks the script on the CPU")
    models = ["smolvla"] if args.smoke else args.models
    out = args.out or (None if args.smoke else ROOT / "benchmarks" / "results")
    header = {"device": torch.cuda.get_device_name() if device == "cuda" else "cpu (--smoke)",
              "torch": torch.__version__, "lerobot": lerobot.__version__, "models": models,
              "episode_steps": STEPS, "fast_path": FAST_PATH, "lerobot_loop": LEROBOT_LOOP}
    results = Results(out / "gpu_throughput.json" if out else None, header)
    for kind in models:
        with tempfile.TemporaryDirectory() as tmp:
            if kind == "pi0":
                cache_paligemma_tokenizer(cache, write_backbone(Path(tmp) / "tokenizer", "tiny"))
            folder = checkpoint(kind, Path(tmp) / kind, device, args.smoke)
            measure(kind, folder, env_factory, device, args.smoke, results)
    results.write(finished=True)
    wall = time.perf_counter() - results.started
    print(f"{'smoke run' if args.smoke else 'run'}: {wall:.0f} s"
          + (f", wrote {results.path}" if results.path else ""))


if __name__ == "__main__":
    main()

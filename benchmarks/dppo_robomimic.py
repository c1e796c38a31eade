"""A DPPO checkpoint trained here on robomimic demonstrations, then measured.

Collects scripted-expert demonstrations on robomimic/lift (can, square or transport), fits DPPO's
normalization to them and pre-trains DPPO's DiffusionMLP as DPPO's robomimic pre-training does (Ren
et al., "Diffusion Policy Policy Optimization", arXiv:2409.00588; github.com/irom-princeton/dppo):
- data as DPPO's script/dataset/process_robomimic_dataset.py and agent/dataset/sequence.py make it:
  obs_min/obs_max/action_min/action_max over every demonstration step, observations and actions
  scaled to [-1, 1] by 2 (x - min) / (max - min + 1e-6) - 1, and one training pair per step t whose
  chunk of horizon_steps actions ends inside its episode (DPPO's StitchedSequenceDataset pads
  nothing: the last horizon_steps - 1 steps of an episode start no chunk);
- cfg/robomimic/pretrain/<task>/pre_diffusion_mlp.yaml's network and training: cond_steps 1,
  denoising_steps 20 (cosine schedule), a residual DiffusionMLP (Mish) of the task's size (RECIPES:
  horizon_steps 4, time_dim 16, mlp_dims [512, 512, 512] on Lift and Can; time_dim 32, mlp_dims
  [1024, 1024, 1024] and cond_mlp_dims [512, 64] on Square; horizon_steps 8, time_dim 32, mlp_dims
  [1024, 1024, 1024] on Transport); epsilon prediction (t uniform over the 20 timesteps); AdamW,
  batch 256, learning rate 1e-4, weight decay 1e-6, DPPO's cosine schedule per epoch (linear warm-up
  from 1e-5 over 100 epochs, then down to 1e-5 at the last epoch); EMA with decay 0.995, updated
  every 10 batches, the weights themselves until epoch 20; act_steps = horizon_steps (DPPO's eval
  configs).

Changed: the data are scripted-expert demonstrations instead of robomimic's human ones, few and noisy
so the policy is imperfect (RECIPES: 20 successful ones on Lift and Can, each demonstrator aiming
off-centre by up to 2 cm, with Gaussian action noise of std 0.3 on Lift, 0.2 on Can; Square and
Transport as their flow and DDIM policies in the zoo learn them), and training runs whole epochs
making about --steps gradient steps rather than DPPO's 3000 epochs (on a few hundred chunks, 3000
epochs are a few thousand steps); every other value is DPPO's.
Training is deterministic for --seed on one thread (an explicit torch.Generator draws the batches,
timesteps and noise). The checkpoint is written in DPPO's format (state_<epoch>.pt, config.yaml,
normalization.npz, with training.json beside them) to --out, then its base policy and zero ticket run
through goldenticket's evaluation on the first --heldout held-out seeds, as the checkpoint's config
runs it (DDIM over its 20 timesteps). Resumable: the demonstrations are kept in a hidden file beside
--out until the checkpoint is written, a training is written to a hidden folder that becomes --out
when complete, an --out holding a finished training is measured, not retrained, and the measurement
records each episode as it ends, so a killed run, run again, runs only what it had not finished.

    ~/.venvs/robomimic/bin/python benchmarks/dppo_robomimic.py [--task lift] [--workers 2]

With the default --demos, --steps, --heldout and --seed, writes benchmarks/results/dppo_<task>.json;
with any other, <out>/measured.json, so a trial run never replaces the recorded numbers.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from build_zoo import ROBOMIMIC
from results_files import RESULTS
from torch.nn import functional
from tqdm import tqdm

from goldenticket import kernels
from goldenticket.errors import UserError
from goldenticket.files import new_folder_beside, write_atomic
from goldenticket.policies.dppo import DiffusionMLP, NetworkSpec, alphas_cumprod, save_checkpoint
from goldenticket.seeds import seeds_in
from goldenticket.tasks import get_task
from goldenticket.train import (
    Demos,
    DemoStyle,
    episodes_seconds,
    forget_kept_demos,
    kept_demos,
    measure,
    measurement_store,
)


@dataclass(frozen=True)
class Recipe:
    """A task's demonstrations and DPPO's network for it: its pre_diffusion_mlp.yaml's horizon_steps,
    time_dim, mlp_dims and cond_mlp_dims."""

    demos: int
    style: DemoStyle
    horizon_steps: int = 4
    time_dim: int = 16
    mlp_dims: tuple[int, ...] = (512, 512, 512)
    cond_mlp_dims: tuple[int, ...] | None = None

    def network(self, obs_dim: int, action_dim: int) -> NetworkSpec:
        return NetworkSpec(action_dim=action_dim, horizon_steps=self.horizon_steps,
                           cond_dim=obs_dim * COND_STEPS, time_dim=self.time_dim, mlp_dims=self.mlp_dims,
                           cond_mlp_dims=self.cond_mlp_dims, residual_style=True)


WIDE = (1024, 1024, 1024)
RECIPES = {"lift": Recipe(20, DemoStyle(grasp_offset=0.02, action_noise=0.3)),
           "can": Recipe(20, DemoStyle(grasp_offset=0.02, action_noise=0.2)),
           "square": Recipe(*ROBOMIMIC["robomimic/square"], time_dim=32, mlp_dims=WIDE,
                            cond_mlp_dims=(512, 64)),
           "transport": Recipe(*ROBOMIMIC["robomimic/transport"], horizon_steps=8, time_dim=32,
                               mlp_dims=WIDE)}
COND_STEPS, DENOISING_STEPS = 1, 20
BATCH, LEARNING_RATE, WEIGHT_DECAY, MIN_LR, WARMUP_EPOCHS = 256, 1e-4, 1e-6, 1e-5, 100
EMA_DECAY, EMA_EVERY, EMA_START = 0.995, 10, 20  # EMA_EVERY in batches, EMA_START in epochs (from 1)
STEPS, HELDOUT, SEED = 30_000, 200, 42  # SEED: DPPO's


def normalization(demos: Demos) -> dict[str, np.ndarray]:
    """DPPO's normalization.npz: per-dimension min and max over every step of every demonstration."""
    obs, actions = np.concatenate(demos.obs), np.concatenate(demos.actions).astype(np.float64)
    return {"obs_min": obs.min(0), "obs_max": obs.max(0), "action_min": actions.min(0),
            "action_max": actions.max(0)}


def dataset(demos: Demos, norm: dict[str, np.ndarray], horizon_steps: int
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """DPPO's training pairs, scaled to [-1, 1]: observations [N, obs_dim] and action chunks
    [N, horizon_steps, action_dim], one per step whose chunk ends inside its episode."""
    starts = [(o, a, t) for o, a in zip(demos.obs, demos.actions, strict=True)
              for t in range(len(a) - horizon_steps + 1)]
    obs = np.stack([o[t] for o, _, t in starts])
    chunks = np.stack([a[t : t + horizon_steps] for _, a, t in starts]).astype(np.float64)

    def scaled(x, low, high):
        return torch.as_tensor(2 * (x - low) / (high - low + 1e-6) - 1, dtype=torch.float32)

    return (scaled(obs, norm["obs_min"], norm["obs_max"]),
            scaled(chunks, norm["action_min"], norm["action_max"]))


def learning_rate(epoch: int, epochs: int) -> float:
    """DPPO's CosineAnnealingWarmupRestarts over one cycle of `epochs`, at 0-based `epoch`."""
    warmup = min(WARMUP_EPOCHS, epochs - 1)
    if epoch < warmup:
        return MIN_LR + (LEARNING_RATE - MIN_LR) * epoch / warmup
    cosine = (1 + math.cos(math.pi * (epoch - warmup) / (epochs - warmup))) / 2
    return MIN_LR + (LEARNING_RATE - MIN_LR) * cosine


def epsilon_loss(network: DiffusionMLP, obs: torch.Tensor, x0: torch.Tensor, alphas: torch.Tensor,
                 gen: torch.Generator) -> torch.Tensor:
    """DPPO's DiffusionModel.loss: t ~ U{0..T-1}, x_t = sqrt(a_t) x0 + sqrt(1 - a_t) eps, the mean
    squared error of the predicted eps."""
    t = torch.randint(len(alphas), (len(x0),), generator=gen)
    noise = torch.randn(x0.shape, generator=gen)
    a = alphas[t][:, None, None]
    return functional.mse_loss(network(a.sqrt() * x0 + (1 - a).sqrt() * noise, t.float(), obs), noise)


def train(recipe: Recipe, obs: torch.Tensor, chunks: torch.Tensor, *, steps: int, seed: int
          ) -> tuple[DiffusionMLP, DiffusionMLP, list[float], int]:
    """DPPO's pre-training of the recipe's DiffusionMLP on (obs, chunks) for whole shuffled epochs
    making about `steps` gradient steps. Returns the network, its EMA, the mean loss per 1k steps
    (the last over what remains) and the epochs run."""
    torch.set_num_threads(1)  # the thread count changes reduction order: part of reproducibility
    torch.manual_seed(seed)  # the initial weights
    gen = torch.Generator().manual_seed(seed)
    network = DiffusionMLP(recipe.network(obs.shape[1], chunks.shape[2]))
    ema = copy.deepcopy(network)
    alphas = alphas_cumprod(DENOISING_STEPS)
    optimizer = torch.optim.AdamW(network.parameters(), lr=LEARNING_RATE, weight_decay=WEIGHT_DECAY)
    epochs = max(1, round(steps / math.ceil(len(chunks) / BATCH)))
    losses, running, batches = [], [], 0
    for epoch in tqdm(range(epochs), desc="training", unit="epoch", mininterval=1):
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(epoch, epochs)
        for idx in torch.randperm(len(chunks), generator=gen).split(BATCH):
            loss = epsilon_loss(network, obs[idx], chunks[idx], alphas, gen)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            if batches % EMA_EVERY == 0:
                if epoch + 1 < EMA_START:
                    ema.load_state_dict(network.state_dict())
                else:
                    with torch.no_grad():
                        for average, current in zip(ema.parameters(), network.parameters(), strict=True):
                            average.copy_(average * EMA_DECAY + (1 - EMA_DECAY) * current)
            batches += 1
            running.append(loss.item())
            if len(running) == 1000:
                losses, running = [*losses, sum(running) / 1000], []
    return network, ema, losses + ([sum(running) / len(running)] if running else []), epochs


def settings(demos: int, style: DemoStyle, steps: int, seed: int) -> dict:
    """What a training is made from: an --out trained from other settings is refused."""
    return {"demos": demos, "style": asdict(style), "steps": steps, "seed": seed}


def build(task, recipe: Recipe, out: Path, asked: dict) -> dict:
    """Demonstrations, training and the DPPO checkpoint in `out` from the `asked` settings; the record of it,
    also written there as training.json."""
    partial = new_folder_beside(out)
    try:
        demos = kept_demos(out, task, asked["demos"], DemoStyle(**asked["style"]), asked["seed"])
        norm = normalization(demos)
        obs, chunks = dataset(demos, norm, recipe.horizon_steps)
        start = time.perf_counter()
        network, ema, losses, epochs = train(recipe, obs, chunks, steps=asked["steps"], seed=asked["seed"])
        train_s = time.perf_counter() - start
        save_checkpoint(partial, network, norm, denoising_steps=DENOISING_STEPS, cond_steps=COND_STEPS,
                        epoch=epochs, ema=ema)  # act_steps: horizon_steps
        record = {"task": task.name, "settings": asked, "demo_attempts": demos.attempts,
                  "demo_steps": int(sum(len(a) for a in demos.actions)), "training_pairs": len(chunks),
                  "epochs": epochs, "train_steps": epochs * math.ceil(len(chunks) / BATCH),
                  "loss_per_1k_steps": [round(x, 5) for x in losses],
                  "wall_s": {"demos": round(demos.seconds, 1), "train": round(train_s, 1)}}
        write_atomic(partial / "training.json", json.dumps(record, indent=2) + "\n")
        if out.exists():
            out.rmdir()
        partial.rename(out)
        forget_kept_demos(out)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return record


def run(args: argparse.Namespace) -> None:
    task = get_task(f"robomimic/{args.task}")
    recipe = RECIPES[args.task]
    asked = settings(args.demos or recipe.demos, recipe.style, args.steps, args.seed)
    out = args.out or Path("runs") / f"dppo-{args.task}"
    seeds_in("heldout", args.heldout)  # a UserError now, not after training
    if (out / "training.json").is_file():
        record = json.loads((out / "training.json").read_text())
        if record["settings"] != asked:
            raise UserError(f"{out} holds a training from other settings ({record['settings']}); choose "
                            "another --out")
        forget_kept_demos(out)  # where a run was killed between writing the checkpoint and this
        print(f"{out}: trained before; measuring it")
    elif out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f"--out {out} exists and holds no finished training; choose a new folder")
    else:
        record = build(task, recipe, out, asked)
    start = time.perf_counter()
    with measurement_store(out, out) as store:  # a killed measurement resumes
        measured = measure(out, task, args.heldout, args.workers, noise_shape=(recipe.horizon_steps,
                                                                               task.action_dim), store=store)
        episodes = episodes_seconds(store)
    record |= {"policy": str(out), "ddim_steps": DENOISING_STEPS, "heldout": args.heldout} | measured
    record["wall_s"] |= {"measure": round(time.perf_counter() - start, 1), "measure_workers": args.workers,
                         "measure_episodes": episodes}
    official = asked == settings(recipe.demos, recipe.style, STEPS, SEED) and args.heldout == HELDOUT
    path = RESULTS / f"dppo_{args.task}.json" if official else out / "measured.json"
    write_atomic(path, json.dumps(record, indent=2) + "\n")
    for arm in ("base", "zero"):
        r = measured[arm]
        print(f"{arm:>4}: {r['success_rate']:.1%} (95% Wilson [{r['ci_low']:.1%}, {r['ci_high']:.1%}], "
              f"n={r['n']})")
    print(f"Wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=list(RECIPES), default="lift")
    parser.add_argument("--demos", type=int, default=None, help="demonstrations (default: the task's recipe)")
    parser.add_argument("--steps", type=int, default=STEPS, help="gradient steps, about (whole epochs)")
    parser.add_argument("--heldout", type=int, default=HELDOUT, help="held-out seeds measured")
    parser.add_argument("--seed", type=int, default=SEED, help="of the demonstrations and the training")
    parser.add_argument("--workers", type=int, default=2, help="evaluation worker processes")
    parser.add_argument("--out", type=Path, default=None, help="checkpoint (default: runs/dppo-<task>)")
    try:
        run(parser.parse_args())
    except UserError as exc:
        raise SystemExit(f"error: {exc}") from None


if __name__ == "__main__":
    kernels.restart_pinned(["robomimic/"])  # as the CLI pins, before any work
    main()

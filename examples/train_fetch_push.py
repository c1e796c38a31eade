"""Train the FetchPush policy of fetch_push.py on noisy scripted demonstrations and write
fetch_push.safetensors (python examples/train_fetch_push.py; 81 s on 2 CPUs here).

The expert's actions are perturbed by Gaussian noise (std 0.2) as they are executed and recorded,
and only successful episodes are kept: a policy cloned from them succeeds often, not always.
"""

import sys
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import save_file

sys.path.insert(0, str(Path(__file__).parent))
from fetch_push import ACTION_DIM, HORIZON, OBS_KEYS, WEIGHTS, Denoiser, expert, make_env, scheduler

DEMOS, TRAIN_SEEDS = 300, range(2_000_000, 3_000_000)  # goldenticket's training seed set


def demonstrations(n: int, rng: np.random.Generator) -> tuple[dict, np.ndarray]:
    """Observations and the action chunks that followed them, from `n` successful episodes."""
    env, obs_rows, chunks, seeds = make_env(), {k: [] for k in OBS_KEYS}, [], iter(TRAIN_SEEDS)
    while n:
        obs, _ = env.reset(seed=next(seeds))
        episode, actions = [], []
        for _ in range(50):
            action = np.clip(expert(obs) + rng.normal(0, 0.2, ACTION_DIM), -1, 1)
            episode.append(obs)
            actions.append(action)
            obs, _, _, _, info = env.step(action)
            if info["is_success"]:
                break
        if not info["is_success"]:
            continue
        n -= 1
        padded = np.concatenate([actions, np.repeat(actions[-1:], HORIZON, 0)])
        for i, o in enumerate(episode):
            for k in OBS_KEYS:
                obs_rows[k].append(o[k])
            chunks.append(padded[i : i + HORIZON])
    return {k: torch.tensor(np.array(v), dtype=torch.float32) for k, v in obs_rows.items()}, \
        torch.tensor(np.array(chunks), dtype=torch.float32)


def train(obs: dict, chunks: torch.Tensor, steps: int = 20000, batch: int = 256) -> Denoiser:
    """Epsilon-prediction loss on DDIM's training schedule."""
    torch.manual_seed(0)
    network, noise_schedule = Denoiser(), scheduler()
    flat = torch.cat([obs[k] for k in OBS_KEYS], 1)
    network.obs_mean.copy_(flat.mean(0))
    network.obs_std.copy_(flat.std(0).clamp_min(1e-3))
    optimizer = torch.optim.AdamW(network.parameters(), lr=1e-3, weight_decay=1e-4)
    lr = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    for step in range(steps):
        rows = torch.randint(len(chunks), (batch,))
        noise, t = torch.randn(batch, HORIZON, ACTION_DIM), torch.randint(0, 100, (batch,))
        noisy = noise_schedule.add_noise(chunks[rows], noise, t)
        loss = torch.nn.functional.mse_loss(network(noisy, t, {k: v[rows] for k, v in obs.items()}), noise)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        lr.step()
        if step % 1000 == 0 or step == steps - 1:
            print(f"step {step}: loss {loss.item():.4f}")
    return network


if __name__ == "__main__":
    obs, chunks = demonstrations(DEMOS, np.random.default_rng(0))
    print(f"{DEMOS} demonstrations, {len(chunks)} chunks")
    save_file(train(obs, chunks).state_dict(), str(WEIGHTS))
    print(f"wrote {WEIGHTS}")

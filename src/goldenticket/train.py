"""Demonstrations from Meta-World's scripted experts, and deterministic policy training."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from goldenticket.errors import UserError
from goldenticket.policies.mlp import Denoiser, MLPPolicy, PolicyConfig, ddim_alpha_bar
from goldenticket.tasks import MetaWorldTask, seeds_in


@dataclass(frozen=True)
class DemoStyle:
    """How imperfect the demonstrators are.

    Each demonstration comes from an expert with its own habit: it sees the object shifted by
    a constant offset drawn per episode from U(-offset, offset) in x and y, so it grasps
    off-centre in its own way; on top, Gaussian action noise. Only successful demos are kept.
    """

    grasp_offset: float = 0.0
    action_noise: float = 0.0


@dataclass
class Demos:
    obs: list[np.ndarray]  # per episode [T, obs_dim]
    actions: list[np.ndarray]  # per episode [T, action_dim]
    attempts: int


def collect_demos(task: MetaWorldTask, n: int, style: DemoStyle, seed: int = 0) -> Demos:
    """`n` successful scripted-expert demonstrations on training seeds."""
    from metaworld.policies import ENV_POLICY_MAP

    if task.env_name not in ENV_POLICY_MAP:
        raise UserError(f"no scripted expert for {task.name}")
    expert, env = ENV_POLICY_MAP[task.env_name](), task.make_env()
    rng = np.random.default_rng(seed)
    demos = Demos([], [], 0)
    bar = tqdm(total=n, desc="demonstrations", unit="demo")
    for episode_seed in seeds_in("train", 100 * n):
        if len(demos.obs) == n:
            break
        offset = np.zeros(task.obs_dim)
        offset[4:6] = rng.uniform(-style.grasp_offset, style.grasp_offset, 2)
        obs_seq, act_seq, success = _expert_episode(expert, env, task, episode_seed, offset,
                                                    style.action_noise, rng)
        demos.attempts += 1
        if success:
            demos.obs.append(obs_seq)
            demos.actions.append(act_seq)
            bar.update()
    bar.close()
    return demos


def _expert_episode(expert, env, task, seed, offset, noise, rng):
    obs, obs_seq, act_seq, success = env.reset(seed), [], [], False
    for _ in range(task.max_steps):
        action = expert.get_action(obs.astype(np.float64) + offset)
        action = np.clip(action + noise * rng.standard_normal(task.action_dim), -1, 1)
        obs_seq.append(obs)
        act_seq.append(action.astype(np.float32))
        obs, _, success = env.step(action)
        if success:
            break
    return np.array(obs_seq), np.array(act_seq), success


def chunk_dataset(demos: Demos, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """(obs_t, actions t..t+H-1) pairs; past the end, the last action repeats."""
    obs, chunks = [], []
    for o, a in zip(demos.obs, demos.actions, strict=True):
        padded = np.concatenate([a, np.repeat(a[-1:], horizon - 1, axis=0)])
        obs.append(o)
        chunks.append(np.stack([padded[t : t + horizon] for t in range(len(a))]))
    return np.concatenate(obs), np.concatenate(chunks)


def train_policy(cfg: PolicyConfig, demos: Demos, *, steps: int = 20_000, batch: int = 256,
                 lr: float = 1e-3, seed: int = 0) -> tuple[MLPPolicy, list[float]]:
    """Train a denoiser on demo chunks; deterministic for a seed. Returns policy and loss curve."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    obs_np, act_np = chunk_dataset(demos, cfg.horizon)
    model = Denoiser(cfg)
    model.obs_mean.copy_(torch.as_tensor(obs_np.mean(0)))
    model.obs_std.copy_(torch.as_tensor(obs_np.std(0) + 1e-3))
    obs = model.normalise_obs(torch.as_tensor(obs_np))
    act = model.normalise_actions(torch.as_tensor(act_np))
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    losses, running = [], 0.0
    for step in tqdm(range(steps), desc=f"training {cfg.name}", unit="step", mininterval=1):
        idx = torch.randint(len(obs), (batch,), generator=gen)
        loss = _denoising_loss(model, cfg, obs[idx], act[idx], gen)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        running += loss.item()
        if (step + 1) % 1000 == 0:
            losses.append(running / 1000)
            running = 0.0
    return MLPPolicy(cfg, model), losses


def _denoising_loss(model, cfg, obs, x0, gen):
    noise = torch.randn(x0.shape, generator=gen)
    if cfg.kind == "flow":  # x_t = t * noise + (1 - t) * x0, velocity = noise - x0
        t = torch.rand(len(x0), generator=gen)
        xt = t[:, None, None] * noise + (1 - t[:, None, None]) * x0
        return torch.mean((model(obs, xt, t) - (noise - x0)) ** 2)
    k = torch.randint(cfg.train_timesteps, (len(x0),), generator=gen)
    t = k.float() / (cfg.train_timesteps - 1)
    a = ddim_alpha_bar(t)[:, None, None]
    xt = a.sqrt() * x0 + (1 - a).sqrt() * noise
    return torch.mean((model(obs, xt, t) - noise) ** 2)

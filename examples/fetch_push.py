"""FetchPush from gymnasium-robotics with a DDIM policy on the diffusers adapter: the env
factory, the scripted expert whose demonstrations trained the policy (`train_fetch_push.py`),
and the policy factory. From the repository root:

    goldenticket search --policy examples.fetch_push:make_policy --task examples.fetch_push:make_env \
        --out runs/fetch-push
"""

import contextlib
import io
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from diffusers import DDIMScheduler
from safetensors.torch import load_file

from goldenticket.policies.diffusers import SchedulerPolicy

WEIGHTS = Path(__file__).with_name("fetch_push.safetensors")
HORIZON, N_EXEC, ACTION_DIM, STEPS = 8, 4, 4, 10
OBS_KEYS = ("observation", "desired_goal")  # 25 + 3 values


def make_env() -> gym.Env:
    """FetchPush-v4: push the block to the goal within 50 steps; info["is_success"]."""
    with contextlib.redirect_stderr(io.StringIO()):  # gymnasium_robotics prints a notice on import
        import gymnasium_robotics
    gym.register_envs(gymnasium_robotics)
    return gym.make("FetchPush-v4")


def expert(obs: dict) -> np.ndarray:
    """Go over the block to a point behind it (seen from the goal), lower, push to the goal."""
    grip, block, goal = obs["observation"][0:3], obs["observation"][3:6], obs["desired_goal"]
    heading = goal[:2] - block[:2]
    heading /= max(np.linalg.norm(heading), 1e-6)
    offset = grip[:2] - block[:2]
    along, across = offset @ heading, abs(offset @ np.array([-heading[1], heading[0]]))
    behind = block[:2] - 0.06 * heading
    if along < -0.03 and across < 0.015 and grip[2] < block[2] + 0.02:
        target = np.array([*(goal[:2] - 0.04 * heading), block[2]])
    elif np.linalg.norm(grip[:2] - behind) < 0.015:
        target = np.array([*behind, block[2]])
    else:
        target = np.array([*behind, block[2] + 0.08])
    return np.append(np.clip(10 * (target - grip), -1, 1), -1.0)


class Denoiser(torch.nn.Module):
    """Predicts the noise in an action chunk from [normalised obs, noisy chunk, timestep]."""

    def __init__(self, hidden: int = 256):
        super().__init__()
        obs_dim, width = 28, HORIZON * ACTION_DIM
        self.net = torch.nn.Sequential(
            torch.nn.Linear(obs_dim + width + 32, hidden), torch.nn.GELU(),
            torch.nn.Linear(hidden, hidden), torch.nn.GELU(),
            torch.nn.Linear(hidden, hidden), torch.nn.GELU(),
            torch.nn.Linear(hidden, width))
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))

    def forward(self, x: torch.Tensor, t: torch.Tensor, obs: dict) -> torch.Tensor:
        flat = torch.cat([obs[k] for k in OBS_KEYS], 1).to(x.dtype)
        freqs = torch.exp(-math.log(1000.0) * torch.arange(16, dtype=x.dtype) / 16)
        angles = t.to(x.dtype)[:, None] * freqs
        inputs = [(flat - self.obs_mean) / self.obs_std, x.flatten(1), angles.sin(), angles.cos()]
        return self.net(torch.cat(inputs, 1)).view_as(x)


def scheduler() -> DDIMScheduler:
    return DDIMScheduler(num_train_timesteps=100, prediction_type="epsilon", clip_sample=True)


def make_policy() -> SchedulerPolicy:
    """The trained policy: 10 DDIM steps, chunks of 8 actions of which 4 are executed."""
    network = Denoiser()
    network.load_state_dict(load_file(str(WEIGHTS)))
    return SchedulerPolicy(network, scheduler(), noise_shape=(HORIZON, ACTION_DIM), n_exec=N_EXEC,
                           steps=STEPS, name="fetch-push-ddim")

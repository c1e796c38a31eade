"""Scheduler policies (diffusers) written outside goldenticket, named by import strings in tests; apart
from byo_example, whose import (in every process that checks its envs' seeding) needs no torch."""

import torch


class TinyDenoiser(torch.nn.Module):
    """A denoising network with random weights (seed 0) on [noisy chunk, timestep, pos, goal]."""

    def __init__(self, horizon: int = 4, action_dim: int = 2):
        super().__init__()
        with torch.random.fork_rng():
            torch.manual_seed(0)
            self.net = torch.nn.Sequential(torch.nn.Linear(horizon * action_dim + 5, 64), torch.nn.GELU(),
                                           torch.nn.Linear(64, horizon * action_dim))

    def forward(self, x, t, obs):
        inputs = [x.flatten(1), t[:, None].float() / 1000, obs["pos"], obs["goal"]]
        return self.net(torch.cat(inputs, 1)).view_as(x)


def make_ddim_policy(prediction_type: str = "epsilon"):
    from diffusers import DDIMScheduler

    from goldenticket.policies.diffusers import SchedulerPolicy

    scheduler = DDIMScheduler(num_train_timesteps=100, prediction_type=prediction_type)
    return SchedulerPolicy(TinyDenoiser(), scheduler, noise_shape=(4, 2), n_exec=2, steps=5)


def make_flow_policy():
    from diffusers import FlowMatchEulerDiscreteScheduler

    from goldenticket.policies.diffusers import SchedulerPolicy

    return SchedulerPolicy(TinyDenoiser(), FlowMatchEulerDiscreteScheduler(), noise_shape=(4, 2),
                           n_exec=2, steps=5)

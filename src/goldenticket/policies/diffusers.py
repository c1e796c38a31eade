"""A NoisePolicy from any denoising network and a `diffusers` scheduler, the way research code
such as Diffusion Policy builds them (DDIM, eta = 0, or flow-matching Euler).

    policy = SchedulerPolicy(network, DDIMScheduler(prediction_type="epsilon"),
                             noise_shape=(16, 7), n_exec=8, steps=10)

`network(sample [B, H, A], timestep [B], obs)` returns what the scheduler's `prediction_type`
names (epsilon, sample or v-prediction for DDIM; the velocity for flow matching); `obs` is the
batch as the env gives it, as float32 tensors (a dict stays a dict). Requires `pip install
diffusers`.
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from goldenticket.policies.mlp import state_hash


class SchedulerPolicy:
    """Denoises the injected noise with `network` and `scheduler` in `steps` steps; the first
    `n_exec` actions of the chunk are executed. Deterministic given (obs, noise)."""

    def __init__(self, network: torch.nn.Module, scheduler, *, noise_shape: tuple[int, int],
                 n_exec: int, steps: int, name: str = "diffusers-policy"):
        self.network, self.scheduler = network.eval(), scheduler
        self.noise_shape, self.n_exec, self.steps, self.name = tuple(noise_shape), n_exec, steps, name

    @torch.no_grad()
    def act(self, obs, noise: np.ndarray) -> np.ndarray:
        scheduler = copy.deepcopy(self.scheduler)  # schedulers keep a step index between calls
        scheduler.set_timesteps(self.steps)
        x = torch.tensor(noise, dtype=torch.float32)
        cond = _tensors(obs)
        for t in scheduler.timesteps:
            out = self.network(x, t.expand(len(x)), cond)
            x = scheduler.step(out, t, x).prev_sample
        return x[:, : self.n_exec].numpy()

    def fingerprint(self) -> str:
        """Weights hash and step count, so that tickets name what they were found for."""
        return f"{state_hash(self.network.state_dict())}@{self.steps}"


def _tensors(obs):
    if isinstance(obs, dict):
        return {key: torch.as_tensor(np.asarray(value), dtype=torch.float32) for key, value in obs.items()}
    return torch.as_tensor(np.asarray(obs), dtype=torch.float32)

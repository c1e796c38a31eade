"""A NoisePolicy from any denoising network and a `diffusers` scheduler, the way research code
such as Diffusion Policy builds them (DDIM, eta = 0, or flow-matching Euler).

    policy = SchedulerPolicy(network, DDIMScheduler(prediction_type="epsilon"),
                             noise_shape=(16, 7), n_exec=8, steps=10)

`network(sample [B, H, A], timestep [B], obs)` returns what the scheduler's `prediction_type`
names (epsilon, sample or v-prediction for DDIM; the velocity for flow matching); `obs` is the
batch as the env gives it, as float64 tensors (a dict stays a dict): the network runs on a
float64 copy of its weights. Requires `pip install diffusers`.
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from goldenticket.policies.numerics import float64, in_blocks, on_grid, state_hash


class SchedulerPolicy:
    """Denoises the injected noise with `network` and `scheduler` in `steps` steps; the first
    `n_exec` actions of the chunk are executed. Deterministic given (obs, noise), with the same
    actions on every CPU: a float64 copy of the network runs in fixed blocks and the actions are
    rounded to a grid (`policies/numerics.py`)."""

    def __init__(self, network: torch.nn.Module, scheduler, *, noise_shape: tuple[int, int],
                 n_exec: int, steps: int, name: str = "diffusers-policy"):
        self.network, self.scheduler = network.eval(), scheduler
        self._network = copy.deepcopy(network).double().eval()
        self.noise_shape, self.n_exec, self.steps, self.name = tuple(noise_shape), n_exec, steps, name

    def act(self, obs, noise: np.ndarray) -> np.ndarray:
        return on_grid(in_blocks(self._denoise, float64(obs), noise)[:, : self.n_exec])

    def _denoise(self, obs, x: torch.Tensor) -> torch.Tensor:
        scheduler = copy.deepcopy(self.scheduler)  # schedulers keep a step index between calls
        scheduler.set_timesteps(self.steps)
        for t in scheduler.timesteps:
            x = scheduler.step(self._network(x, t.expand(len(x)), obs), t, x).prev_sample
        return x

    def fingerprint(self) -> str:
        """Weights hash and step count, so that tickets name what they were found for."""
        return f"{state_hash(self.network.state_dict())}@{self.steps}"

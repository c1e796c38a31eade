"""Inference that gives the same actions on every CPU.

Math kernels (MKL, ATen SIMD) differ between CPUs in the last bits, and rollouts are chaotic, so
policies run their network in float64, where kernels differ by < 1e-13, and round the actions
once to multiples of GRID (2^-20, far below any actuator's resolution): a kernel difference
changes an action only if it straddles a grid point, measured at ~3e-10 per action value
(docs/how-to/reproducibility.md). The network runs on fixed blocks of BLOCK rows, the
last zero-padded, so each row's actions are bitwise independent of its batch, on one torch
thread (these matmuls are small: threads only cost, ~100x on a busy CPU).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable

import numpy as np
import torch

BLOCK = 16  # rows per network call
GRID = 2.0**-20  # actions are rounded to multiples of this


def float64(obs) -> torch.Tensor | dict[str, torch.Tensor]:
    """A batch of observations (an array or a dict of arrays) as float64 tensors (copies)."""
    if isinstance(obs, dict):
        return {key: torch.tensor(np.asarray(value), dtype=torch.float64) for key, value in obs.items()}
    return torch.tensor(np.asarray(obs), dtype=torch.float64)


def in_blocks(denoise: Callable, obs, noise: np.ndarray) -> torch.Tensor:
    """`denoise(obs_block, noise_block)` over fixed blocks of BLOCK rows on one torch thread;
    `obs` is a float64 tensor [B, ...] or a dict of them; returns the float64 result [B, ...]."""
    n, pad = len(noise), -len(noise) % BLOCK
    padded = {k: _pad(v, pad) for k, v in obs.items()} if isinstance(obs, dict) else _pad(obs, pad)
    x = _pad(torch.tensor(noise, dtype=torch.float64), pad)  # a copy: tickets may be read-only
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.no_grad():
            blocks = [denoise(_rows(padded, i), x[i : i + BLOCK]) for i in range(0, len(x), BLOCK)]
    finally:
        torch.set_num_threads(threads)
    return torch.cat(blocks)[:n]


def on_grid(actions: torch.Tensor) -> np.ndarray:
    """Actions rounded to multiples of GRID, as float32."""
    return (torch.round(actions / GRID) * GRID).to(torch.float32).numpy()


def state_hash(state: dict[str, torch.Tensor]) -> str:
    """16 hex chars of sha256 over a state dict's names and values."""
    digest = hashlib.sha256()
    for key, value in sorted(state.items()):
        digest.update(key.encode())
        digest.update(value.detach().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


def _pad(t: torch.Tensor, rows: int) -> torch.Tensor:
    return torch.cat([t, t.new_zeros((rows, *t.shape[1:]))]) if rows else t


def _rows(obs, i: int):
    return {k: v[i : i + BLOCK] for k, v in obs.items()} if isinstance(obs, dict) else obs[i : i + BLOCK]

"""Where each policy call's initial noise comes from, per episode."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

# A sampler gives the noise for one policy call of one episode.
Sampler = Callable[[], np.ndarray]


@dataclass(frozen=True)
class Gaussian:
    """The base policy: fresh N(0, I) noise at every call, reproducible from the episode seed."""

    seed: int = 0
    label: str = "base"

    def sampler(self, episode_seed: int, shape: tuple[int, int]) -> Sampler:
        rng = np.random.default_rng([self.seed, episode_seed])
        return lambda: rng.standard_normal(shape, dtype=np.float32)


@dataclass(frozen=True, eq=False)
class Constant:
    """A ticket: the same noise at every call."""

    noise: np.ndarray
    label: str = "ticket"

    def sampler(self, episode_seed: int, shape: tuple[int, int]) -> Sampler:
        if self.noise.shape != tuple(shape):
            raise ValueError(f"ticket shape {self.noise.shape} != policy noise shape {shape}")
        return lambda: self.noise


@dataclass(frozen=True, eq=False)
class TopK:
    """Stochastic tickets: one of k tickets, drawn uniformly at every call; with probability
    `epsilon`, fresh N(0, I) noise instead. Seeded by the episode."""

    tickets: np.ndarray  # [k, H, A]
    seed: int = 0
    epsilon: float = 0.0
    label: str = field(default="mixture")

    def sampler(self, episode_seed: int, shape: tuple[int, int]) -> Sampler:
        if self.tickets.shape[1:] != tuple(shape):
            raise ValueError(f"ticket shape {self.tickets.shape[1:]} != policy noise shape {shape}")
        rng = np.random.default_rng([self.seed, episode_seed])

        def draw() -> np.ndarray:
            if self.epsilon > 0 and rng.random() < self.epsilon:
                return rng.standard_normal(shape, dtype=np.float32)
            return self.tickets[rng.integers(len(self.tickets))]
        return draw


NoiseSource = Gaussian | Constant | TopK

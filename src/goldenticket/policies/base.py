"""The NoisePolicy contract: a policy whose only randomness is an injected noise array."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class NoisePolicy(Protocol):
    """Maps (observation, initial noise) to an action chunk, deterministically.

    `noise_shape` is (H, A): prediction horizon x action dim. `act` returns the first
    `n_exec` actions of each predicted chunk; the caller replans after executing them. Each
    row's actions must not depend on the other rows, so that an episode's result does not
    depend on its batch slot. Observations come as the env gives them, stacked over the batch:
    an array [B, ...] (any float dtype) or a dict of such arrays (camera images and state).
    Optional: `name`, and `fingerprint()` naming the weights (tickets record it).
    """

    name: str
    noise_shape: tuple[int, int]
    n_exec: int

    def act(self, obs: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """obs [B, ...] or {key: [B, ...]}, noise [B, H, A] float32 -> actions [B, n_exec, A]."""
        ...


class TicketedPolicy:
    """Deployment: a NoisePolicy that always uses one ticket; `act(obs)` needs no noise."""

    def __init__(self, policy: NoisePolicy, noise: np.ndarray):
        self.policy = policy
        self.use(noise)

    @property
    def noise_shape(self) -> tuple[int, int]:
        """(H, A): the ticket's shape, the policy's noise shape."""
        return tuple(self.policy.noise_shape)

    @property
    def n_exec(self) -> int:
        """Actions each `act` returns per observation, to execute before calling again."""
        return self.policy.n_exec

    def use(self, noise: np.ndarray) -> None:
        """Switch to another ticket (e.g. another point of a Pareto front) between episodes; the
        model stays loaded."""
        if tuple(noise.shape) != tuple(self.policy.noise_shape):
            raise ValueError(f"ticket shape {noise.shape} != policy noise shape {self.policy.noise_shape}")
        self.noise = np.asarray(noise, dtype=np.float32)

    def act(self, obs: np.ndarray | dict[str, np.ndarray]) -> np.ndarray:
        """obs [B, ...] or {key: [B, ...]} -> actions [B, n_exec, A], the ticket broadcast over
        the batch."""
        return self.policy.act(obs, np.broadcast_to(self.noise, (batch_size(obs), *self.noise.shape)))


def batch_size(obs: np.ndarray | dict[str, np.ndarray]) -> int:
    """B, the leading dimension of a batch of observations: an array [B, ...] or a dict of them."""
    arrays = list(obs.values()) if isinstance(obs, dict) else [obs]
    sizes = {len(np.asarray(a)) for a in arrays}
    if len(sizes) != 1:
        raise ValueError(f"observation arrays disagree on the batch size: {sorted(sizes)}")
    return sizes.pop()

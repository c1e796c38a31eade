"""A ticket inside LeRobot's own loops: `with_ticket(policy, ticket)` is a LeRobot policy that starts
every chunk it draws from the ticket, called as LeRobot's loops call any policy: `reset()` and
`select_action(batch)` (`lerobot-eval`'s `eval_policy`, `lerobot-rollout`'s robot loop,
`predict_action`), `predict_action_chunk(batch, ...)` (real-time chunking)."""

from __future__ import annotations

import functools
import inspect

import numpy as np
import torch

from goldenticket.errors import UserError
from goldenticket.policies.lerobot.checkpoint import STEERED


def noise_shape(config) -> tuple[int, int]:
    """The initial noise one row of a LeRobot policy with this config draws: diffusion's
    (horizon, action_dim), a VLA's (chunk_size, max_action_dim)."""
    if config.type == "diffusion":
        return config.horizon, config.action_feature.shape[0]
    return config.chunk_size, config.max_action_dim


class Ticketed:
    """Put before a LeRobot policy class: the noise of every chunk is `self.ticket`, broadcast over
    the batch. Where `select_action` takes `noise` (diffusion, SmolVLA) it is passed there; where it
    does not (pi0, pi0.5), its call to `predict_action_chunk` passes it."""

    ticket: torch.Tensor

    def select_action(self, batch: dict, **kwargs) -> torch.Tensor:
        if "noise" in inspect.signature(super().select_action).parameters:
            kwargs.setdefault("noise", self.ticket_for(batch))
        return super().select_action(batch, **kwargs)

    def predict_action_chunk(self, batch: dict, **kwargs) -> torch.Tensor:
        kwargs.setdefault("noise", self.ticket_for(batch))
        return super().predict_action_chunk(batch, **kwargs)

    def ticket_for(self, batch: dict) -> torch.Tensor:
        """The ticket once per row of `batch`, on its device."""
        rows = next(value for value in batch.values() if isinstance(value, torch.Tensor))
        return self.ticket.to(rows.device).expand(len(rows), *self.ticket.shape)


@functools.cache
def ticketed_class(policy_class: type) -> type:
    """`Ticketed` before `policy_class`, made once per class."""
    return type(f"Ticketed{policy_class.__name__}", (Ticketed, policy_class), {})


def with_ticket(policy, ticket):
    """`policy`, a LeRobot diffusion (DDIM), SmolVLA, pi0 or pi0.5 policy, acting with `ticket` (a
    Ticket, or an array of the policy's noise shape) as its initial noise: an instance of a subclass
    of the policy's class sharing its weights, with action and observation queues of its own, so
    LeRobot's loops take it where they take `policy`. One-line UserError for a policy or a ticket
    that do not fit."""
    config = policy.config
    if config.type not in STEERED or getattr(config, "noise_scheduler_type", "DDIM") != "DDIM":
        raise UserError(f"a ticket steers LeRobot's {', '.join(STEERED)} policies (diffusion under DDIM), "
                        f"not this {config.type} policy")
    noise = np.asarray(getattr(ticket, "noise", ticket), dtype=np.float32)
    if noise.shape != noise_shape(config):
        raise UserError(f"the ticket's noise has shape {noise.shape}; this {config.type} policy draws "
                        f"{noise_shape(config)}")
    cls = ticketed_class(type(policy))
    ticketed = cls.__new__(cls)
    ticketed.__dict__.update(policy.__dict__)
    ticketed.ticket = torch.tensor(noise)  # a copy: tickets may be read-only
    ticketed.reset()
    return ticketed

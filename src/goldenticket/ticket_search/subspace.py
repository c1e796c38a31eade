"""Sub-space search: the optimizer searches fewer numbers than the full (H, A) ticket.

- `full`: every entry of the (H, A) ticket.
- `tiled`: one A-dim vector, repeated over the H steps of the horizon.
- `channels:I,J`: the H x k entries of action channels I, J, ...; the other channels' entries are
  zero. Zero rather than fresh Gaussian noise per call, so that a ticket stays one constant
  array (its file, id, evaluation and deployment are those of any ticket), and the zero ticket
  is as good as the base policy on the bundled suite (see the existence table), so the
  unsearched channels start from the base's behaviour, not from a worse one.

Ticket files hold the expanded (H, A) noise and record the sub-space in their metadata.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goldenticket.errors import OptionError


@dataclass(frozen=True)
class Subspace:
    kind: str = "full"
    channels: tuple[int, ...] = ()

    @classmethod
    def parse(cls, text: str, noise_shape: tuple[int, int]) -> Subspace:
        """`full`, `tiled` or `channels:I,J` for a policy with noise shape (H, A); UserError otherwise."""
        kind, _, rest = text.partition(":")
        if kind in ("full", "tiled") and not rest:
            return cls(kind)
        if kind == "channels" and rest:
            try:
                channels = tuple(int(c) for c in rest.split(","))
            except ValueError:
                raise OptionError(f"subspace {text}: channels must be integers, e.g. channels:3",
                                  "subspace") from None
            action_dim = noise_shape[1]
            if len(set(channels)) != len(channels) or not all(0 <= c < action_dim for c in channels):
                raise OptionError(f"subspace {text}: channels must be distinct, in 0..{action_dim - 1} "
                                  f"(the policy's action has {action_dim} dims)", "subspace")
            return cls(kind, tuple(sorted(channels)))
        raise OptionError(f"subspace {text!r}: choose full, tiled or channels:I,J", "subspace")

    def __str__(self) -> str:
        return f"channels:{','.join(map(str, self.channels))}" if self.kind == "channels" else self.kind

    def shape(self, noise_shape: tuple[int, int]) -> tuple[int, int]:
        """The shape the optimizer searches."""
        horizon, action_dim = noise_shape
        return {"full": (horizon, action_dim), "tiled": (1, action_dim),
                "channels": (horizon, len(self.channels))}[self.kind]

    def expand(self, searched: np.ndarray, noise_shape: tuple[int, int]) -> np.ndarray:
        """The full (H, A) ticket of a searched array."""
        searched = np.asarray(searched, dtype=np.float32)
        if self.kind == "full":
            return searched
        if self.kind == "tiled":
            return np.repeat(searched, noise_shape[0], axis=0)
        ticket = np.zeros(noise_shape, dtype=np.float32)
        ticket[:, list(self.channels)] = searched
        return ticket

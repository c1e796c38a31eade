"""What the robot runs for one planned episode, and its JSON on the wire (`GET /api/next`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NextEpisode:
    """What the robot runs next: a ticket's noise for every policy call, or, for the base arm
    (`noise` None), fresh N(0, I) noise of `noise_shape` per call from
    `numpy.random.default_rng(gaussian_seed)`; `noise_source()` gives either as a function."""

    episode: int
    ticket_id: str
    noise: np.ndarray | None
    gaussian_seed: list[int] | None
    noise_shape: tuple[int, int] | None = None

    def to_json(self) -> dict:
        noise = None if self.noise is None else self.noise.tolist()
        return {"episode": self.episode, "ticket_id": self.ticket_id, "noise": noise,
                "gaussian_seed": self.gaussian_seed, "noise_shape": self.noise_shape}

    @classmethod
    def from_json(cls, data: dict) -> NextEpisode:
        noise = None if data["noise"] is None else np.asarray(data["noise"], dtype=np.float32)
        shape = data.get("noise_shape")
        return cls(data["episode"], data["ticket_id"], noise, data["gaussian_seed"],
                   None if shape is None else tuple(shape))

    def noise_source(self):
        """A function returning the noise for the next policy call: the ticket every time, or the
        base arm's next N(0, I) draw."""
        if self.noise is not None:
            return lambda: self.noise
        rng = np.random.default_rng(self.gaussian_seed)
        return lambda: rng.standard_normal(self.noise_shape, dtype=np.float32)

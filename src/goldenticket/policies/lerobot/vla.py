"""LeRobot's flow-matching VLAs, SmolVLA, pi0 and pi0.5: a ticket is the noise their model draws,
(chunk_size, max_action_dim), padded past the robot's action dim as the model pads it; each call
executes the chunk's first `n_action_steps` actions, as `select_action` does; the task's
language instruction goes in as LeRobot's eval passes it ("task" in the batch)."""

from __future__ import annotations

import copy

import torch

from goldenticket.policies.lerobot.checkpoint import LeRobotPolicy
from goldenticket.policies.lerobot.loops import noise_shape


class VLAPolicy(LeRobotPolicy):
    """A LeRobot SmolVLA, pi0 or pi0.5 folder as a NoisePolicy that reads an instruction."""

    @property
    def noise_shape(self) -> tuple[int, int]:
        return noise_shape(self.cfg)

    def instructed(self, instruction: str) -> VLAPolicy:
        """This policy given `instruction` (what LeRobot's eval passes as "task"); the model is shared."""
        policy = copy.copy(self)
        policy.instruction = instruction
        return policy

    def _chunk(self, batch: dict, noise: torch.Tensor) -> torch.Tensor:
        return self.model.predict_action_chunk(batch, noise=noise)[:, : self.n_exec]

"""LeRobot's DiffusionPolicy under DDIM: a ticket is the initial noise of `generate_actions`,
shape (horizon, action_dim); each episode keeps its last `n_obs_steps` observations."""

from __future__ import annotations

import torch

from goldenticket.policies.lerobot.checkpoint import LeRobotPolicy


class DiffusionPolicyAdapter(LeRobotPolicy):
    """A LeRobot DiffusionPolicy folder (DDIM) as a NoisePolicy."""

    @property
    def noise_shape(self) -> tuple[int, int]:
        return self.cfg.horizon, self.cfg.action_feature.shape[0]

    @property
    def denoising_steps(self) -> int:
        return self.model.diffusion.num_inference_steps

    def _batch(self, raw) -> dict:
        """The frames `select_action` queues, with the cameras stacked as `generate_actions` reads them."""
        from lerobot.utils.constants import OBS_IMAGES

        frames = super()._batch(raw)
        if self.n_obs_steps == 1:
            frames = {key: value[:, None] for key, value in frames.items() if isinstance(value, torch.Tensor)}
        if self.cfg.image_features:
            frames[OBS_IMAGES] = torch.stack([frames[key] for key in self.cfg.image_features], dim=-4)
        return {key: value for key, value in frames.items() if key in self.model._queues}

    def _chunk(self, batch: dict, noise: torch.Tensor) -> torch.Tensor:
        return self.model.diffusion.generate_actions(batch, noise=noise)

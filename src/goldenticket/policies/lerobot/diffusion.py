"""LeRobot's DiffusionPolicy under DDIM: a ticket is the initial noise of `generate_actions`,
shape (horizon, action_dim); each episode keeps its last `n_obs_steps` observations."""

from __future__ import annotations

import torch

from goldenticket.errors import UserError
from goldenticket.policies.lerobot.checkpoint import LeRobotPolicy
from goldenticket.policies.lerobot.loops import noise_shape


class DiffusionPolicyAdapter(LeRobotPolicy):
    """A LeRobot DiffusionPolicy folder (DDIM) as a NoisePolicy."""

    @property
    def noise_shape(self) -> tuple[int, int]:
        return noise_shape(self.cfg)

    @property
    def denoising_steps(self) -> int:
        return self.model.diffusion.num_inference_steps

    def _most_actions(self, cfg) -> int:
        """The actions after the observed steps in the horizon `generate_actions` predicts."""
        return cfg.horizon - cfg.n_obs_steps + 1

    def _check_cameras(self, cameras: dict[str, tuple[int, ...]]) -> None:
        """Every camera of the policy, its frames of the size its image encoder takes: any size where
        it resizes them (`resize_shape`), at least its `crop_shape` where it crops them, else its own; a
        camera given by its channels alone (its size is known once the env renders) by its channels."""
        crop = self.cfg.crop_shape
        for key, feature in self.cfg.image_features.items():
            wanted, given = tuple(feature.shape), cameras.get(key)
            if given is None:
                raise UserError(f"policy {self.name!r} reads camera {key!r}, and the env's cameras are "
                                f"{sorted(cameras)}; map one to it with rename_map (--rename-map "
                                f"ENV_KEY={key})")
            given = given + wanted[len(given):]  # a size not known yet: the one the policy takes
            sized = given[1] >= crop[0] and given[2] >= crop[1] if crop else given[1:] == wanted[1:]
            if given[0] != wanted[0] or not (self.cfg.resize_shape is not None or sized):
                takes = f"at least {crop[0]}x{crop[1]} (its crop)" if crop else f"{wanted[1]}x{wanted[2]}"
                raise UserError(f"policy {self.name!r}: camera {key!r} gives {given[0]} x "
                                f"{given[1]}x{given[2]} frames and the diffusion policy's image encoder "
                                f"takes {wanted[0]} x {takes}, without resizing them: train it on this env's "
                                "frames (or with resize_shape)")

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

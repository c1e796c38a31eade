"""LeRobot checkpoints as NoisePolicies: the folder `lerobot-train` writes under
`checkpoints/*/pretrained_model` (config.json, model.safetensors, policy_preprocessor*.json,
policy_postprocessor*.json and their state files), for LeRobot 0.4.4's diffusion policies.

Observations go to the model as in LeRobot's own eval (`lerobot-eval`): its
`preprocess_observation`, then the saved preprocessor pipeline; actions come back through the
saved postprocessor. A ticket is the initial noise of `generate_actions`, shape (horizon,
action_dim); each call executes `n_action_steps` actions. The model runs as LeRobot runs it, in
float32, on fixed blocks of BLOCK rows on one torch thread: each row's actions are bitwise those
LeRobot's `select_action(batch, noise=...)` gives for it in a batch of BLOCK envs, and do not
depend on the other rows. LeRobot is imported only when such a folder is loaded.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
from pathlib import Path

import numpy as np
import torch

from goldenticket.errors import UserError
from goldenticket.policies.numerics import BLOCK

REQUIRED = ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json")
NOISE_TAKERS_UNTESTED = ("pi0", "pi05", "smolvla")  # take noise= too; their backbones are downloaded


def is_checkpoint(path: Path) -> bool:
    """A folder LeRobot wrote: one with policy_preprocessor*.json, or whose config.json has a "type"."""
    if not path.is_dir():
        return False
    if any(path.glob("policy_preprocessor*.json")):
        return True
    try:
        return "type" in json.loads((path / "config.json").read_text())
    except (OSError, ValueError, TypeError):
        return False


def checked_config(path: Path) -> dict:
    """config.json of a LeRobot diffusion checkpoint run with DDIM; a one-line UserError otherwise."""
    missing = [name for name in REQUIRED if not (path / name).is_file()]
    if missing:
        raise UserError(f"{path} is not a LeRobot checkpoint: no {', '.join(missing)} (lerobot-train writes "
                        "them under checkpoints/*/pretrained_model)")
    try:
        config = json.loads((path / "config.json").read_text())
        kind = config["type"]
    except (ValueError, KeyError, TypeError):
        raise UserError(f"{path}/config.json is not a LeRobot policy config (no \"type\")") from None
    if kind in NOISE_TAKERS_UNTESTED:
        raise UserError(f"{path}: LeRobot policy type {kind!r} is not supported (goldenticket runs LeRobot's "
                        "'diffusion' policies; this one needs a downloaded backbone, untested here)")
    if kind != "diffusion":
        raise UserError(f"{path}: LeRobot policy type {kind!r} takes no initial noise, so no ticket can "
                        "steer it (goldenticket runs LeRobot's 'diffusion' policies)")
    scheduler = config.get("noise_scheduler_type")
    if scheduler != "DDIM":
        raise UserError(f"{path}: its {scheduler} scheduler adds fresh noise at every denoising step, so a "
                        "ticket does not fix its actions; run the same weights with DDIM: set "
                        f"\"noise_scheduler_type\": \"DDIM\" in {path / 'config.json'}")
    return config


class LeRobotPolicy:
    """A LeRobot DiffusionPolicy folder as a NoisePolicy; `steps` overrides num_inference_steps."""

    def __init__(self, path: str | Path, steps: int | None = None, name: str | None = None):
        self.path, self.steps = Path(path), steps
        checked_config(self.path)
        try:
            from lerobot.configs.policies import PreTrainedConfig
            from lerobot.policies.factory import get_policy_class, make_pre_post_processors
        except ImportError:
            raise UserError(f"{path} is a LeRobot checkpoint, and LeRobot is not installed here: install it "
                            "as README's \"LeRobot\" section says (pip install -e \".[lerobot]\")") from None
        cfg = PreTrainedConfig.from_pretrained(self.path)
        cfg.device, cfg.num_inference_steps = "cpu", steps or cfg.num_inference_steps
        with contextlib.redirect_stdout(io.StringIO()):  # LeRobot prints where it loads from
            self.model = get_policy_class(cfg.type).from_pretrained(self.path, config=cfg).eval()
        on_cpu = {"device_processor": {"device": "cpu"}}
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            cfg, pretrained_path=str(self.path), preprocessor_overrides=on_cpu)
        self.cfg, self.name = cfg, name or str(path)
        self.noise_shape = (cfg.horizon, cfg.action_feature.shape[0])
        self.n_exec, self.n_obs_steps = cfg.n_action_steps, cfg.n_obs_steps
        self._digest = _files_digest(self.path)

    def __reduce__(self):  # worker processes load the folder again
        return LeRobotPolicy, (self.path, self.steps, self.name)

    def fingerprint(self) -> str:
        """Hash of the folder's config, weights and processor files, and the denoising step count."""
        return f"lerobot-{self._digest}-steps{self.model.diffusion.num_inference_steps}"

    def act(self, obs, noise: np.ndarray) -> np.ndarray:
        """obs: LeRobot env observations ({"agent_pos", "environment_state", "pixels"}: [B, ...], or an
        array taken as "agent_pos"), with n_obs_steps > 1 the last n_obs_steps of each episode
        ([B, n_obs_steps, ...], as rollout gives them); noise [B, horizon, A] -> actions [B, n_exec, A]."""
        history = [obs] if self.n_obs_steps == 1 else [_at(obs, s) for s in range(self.n_obs_steps)]
        frames = [self._frame(o) for o in history]
        keys = [key for key in frames[0] if key in self.model._queues]
        batch = {key: torch.stack([f[key] for f in frames], dim=1) for key in keys}
        noise = torch.as_tensor(np.asarray(noise, dtype=np.float32))
        n, pad = len(noise), -len(noise) % BLOCK
        batch, noise = {k: _padded(v, pad) for k, v in batch.items()}, _padded(noise, pad)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with torch.no_grad():
                chunks = [self.model.diffusion.generate_actions(_rows(batch, i), noise=noise[i : i + BLOCK])
                          for i in range(0, len(noise), BLOCK)]
        finally:
            torch.set_num_threads(threads)
        return self.postprocessor(torch.cat(chunks)[:n]).numpy()

    def _frame(self, obs) -> dict[str, torch.Tensor]:
        """One step's observations of the batch as the model's queues hold them (LeRobot's eval path)."""
        from lerobot.envs.utils import preprocess_observation
        from lerobot.utils.constants import ACTION, OBS_IMAGES

        raw = obs if isinstance(obs, dict) else {"agent_pos": obs}
        tensors = preprocess_observation({k: np.asarray(v) for k, v in raw.items()})
        self._check_features(tensors)
        tensors["task"] = [""] * len(next(iter(tensors.values())))  # as lerobot-eval does for envs without
        frame = self.preprocessor(tensors)
        frame.pop(ACTION, None)  # as select_action does
        if self.cfg.image_features:
            frame[OBS_IMAGES] = torch.stack([frame[key] for key in self.cfg.image_features], dim=-4)
        return frame

    def _check_features(self, tensors: dict[str, torch.Tensor]) -> None:
        """One-line UserError unless the observation has every input feature, in its shape."""
        given = {k: tuple(v.shape[1:]) for k, v in tensors.items()}
        wanted = {k: tuple(f.shape) for k, f in self.cfg.input_features.items()}
        if any(given.get(k) != shape for k, shape in wanted.items()):
            raise UserError(f"policy {self.name!r}: the env's observations give {given} after LeRobot's "
                            f"preprocess_observation; the policy's input features are {wanted}")


def _files_digest(path: Path) -> str:
    digest = hashlib.sha256()
    for file in sorted([*path.glob("policy_*processor*"), path / "config.json", path / "model.safetensors"]):
        digest.update(file.name.encode() + file.read_bytes())
    return digest.hexdigest()[:16]


def _at(obs, step: int):
    """Step `step` of a batch of observation histories: arrays [B, n, ...] or dicts of them."""
    if isinstance(obs, dict):
        return {k: np.asarray(v)[:, step] for k, v in obs.items()}
    return np.asarray(obs)[:, step]


def _rows(batch: dict[str, torch.Tensor], i: int) -> dict[str, torch.Tensor]:
    return {k: v[i : i + BLOCK] for k, v in batch.items()}


def _padded(t: torch.Tensor, rows: int) -> torch.Tensor:
    return torch.cat([t, t.new_zeros((rows, *t.shape[1:]))]) if rows else t

"""What every LeRobot checkpoint adapter shares: the folder's checks, loading the model and its
saved processors, observations as LeRobot's eval loop builds them, and fixed blocks of rows."""

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
STEERED = ("diffusion", "smolvla", "pi0", "pi05")  # policy types whose initial noise can be passed
NOISE_FREE = ("act", "vqbet", "tdmpc", "gaussian_actor", "pi0_fast")  # regress or decode actions
INSTALL = "install it as README's \"LeRobot\" section says (a Python 3.12 venv with lerobot 0.6.1)"


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
    """config.json of a LeRobot checkpoint whose initial noise a ticket can fix; a one-line
    UserError otherwise."""
    missing = [name for name in REQUIRED if not (path / name).is_file()]
    if missing:
        raise UserError(f"{path} is not a LeRobot checkpoint: no {', '.join(missing)} (lerobot-train writes "
                        "them under checkpoints/*/pretrained_model)")
    try:
        config = json.loads((path / "config.json").read_text())
        kind = config["type"]
    except (ValueError, KeyError, TypeError):
        raise UserError(f"{path}/config.json is not a LeRobot policy config (no \"type\")") from None
    steered = f"goldenticket runs LeRobot's {', '.join(STEERED)} policies"
    if kind in NOISE_FREE:
        raise UserError(f"{path}: LeRobot policy type {kind!r} takes no initial noise, so no ticket can "
                        f"steer it ({steered})")
    if kind not in STEERED:
        raise UserError(f"{path}: LeRobot policy type {kind!r} draws its noise inside, with no argument to "
                        f"pass a ticket ({steered})")
    if kind == "diffusion" and config.get("noise_scheduler_type") != "DDIM":
        scheduler = config.get("noise_scheduler_type")
        raise UserError(f"{path}: its {scheduler} scheduler adds fresh noise at every denoising step"
                        ", so a ticket does not fix its actions; run the same weights with DDIM: set "
                        f"\"noise_scheduler_type\": \"DDIM\" in {path / 'config.json'}")
    return config


def lerobot_modules():
    """LeRobot's config loader and policy factory; a one-line UserError where it is not installed."""
    try:
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    except ImportError:
        raise UserError(f"LeRobot is not installed here: {INSTALL}") from None
    return PreTrainedConfig, get_policy_class, make_pre_post_processors


class LeRobotPolicy:
    """A LeRobot checkpoint folder as a NoisePolicy. Subclasses say what the noise is
    (`noise_shape`) and how one block of rows becomes action chunks (`_chunk`); `steps` overrides
    the config's denoising step count (SmolVLA's `num_steps`, the others' `num_inference_steps`)."""

    def __init__(self, path: str | Path, steps: int | None = None, name: str | None = None,
                 device: str = "cpu"):
        self.path, self.steps, self.device = Path(path), steps, device
        checked_config(self.path)
        config_class, policy_class, processors = lerobot_modules()
        cfg = config_class.from_pretrained(self.path)
        cfg.device = device
        overrides = {"device_processor": {"device": device}} | self._backbone_inside(cfg)
        self._steps_field = "num_steps" if hasattr(cfg, "num_steps") else "num_inference_steps"
        if steps:
            setattr(cfg, self._steps_field, steps)
        with contextlib.redirect_stdout(io.StringIO()), _backbone_named(cfg, self.path):
            self.model = policy_class(cfg.type).from_pretrained(self.path, config=cfg).eval()
            self.preprocessor, self.postprocessor = processors(
                cfg, pretrained_path=str(self.path), preprocessor_overrides=overrides)
        self.cfg, self.name = cfg, name or str(path)
        self.n_exec, self.n_obs_steps = cfg.n_action_steps, cfg.n_obs_steps
        self.action_dim = cfg.action_feature.shape[0]  # a VLA pads its noise past it
        self.instruction = ""  # what LeRobot's eval passes as "task" for an env without one
        self._digest = files_digest(self.path)

    @property
    def denoising_steps(self) -> int:
        return getattr(self.cfg, self._steps_field)

    def _backbone_inside(self, cfg) -> dict:
        """A VLA whose `vlm_model_name` is a folder inside the checkpoint (a relative name) reads its
        backbone, and its tokenizer, from there; the processor overrides that say so."""
        name = getattr(cfg, "vlm_model_name", None)
        if not (name and (self.path / name).is_dir()):
            return {}
        cfg.vlm_model_name = str(self.path / name)
        return {"tokenizer_processor": {"tokenizer_name": cfg.vlm_model_name}}

    def __reduce__(self):  # worker processes load the folder again
        return type(self), (self.path, self.steps, self.name, self.device), {"instruction": self.instruction}

    def __copy__(self) -> LeRobotPolicy:  # in this process: the same model
        clone = object.__new__(type(self))
        clone.__dict__.update(self.__dict__)
        return clone

    def fingerprint(self) -> str:
        """Hash of the folder's config, weights and processor files, and the denoising step count."""
        return f"lerobot-{self._digest}-steps{self.denoising_steps}"

    def act(self, obs, noise: np.ndarray) -> np.ndarray:
        """obs: LeRobot env observations ({"agent_pos", "environment_state", "pixels"}: [B, ...], or an
        array taken as "agent_pos"), with n_obs_steps > 1 the last n_obs_steps of each episode
        ([B, n_obs_steps, ...], as rollout gives them); noise [B, *noise_shape] -> actions [B, n_exec, A]."""
        raw = per_array(np.asarray, obs if isinstance(obs, dict) else {"agent_pos": obs})
        noise = torch.tensor(np.asarray(noise, dtype=np.float32))  # a copy: tickets may be read-only
        n = len(noise)
        block = BLOCK if self.device == "cpu" else n  # on a GPU, the whole batch in one call
        rows = -n % block  # padding: copies of the first row, a valid observation
        raw = per_array(lambda v: np.concatenate([v, np.repeat(v[:1], rows, axis=0)]), raw)
        noise = torch.cat([noise, noise[:1].expand(rows, *noise.shape[1:])])
        threads = torch.get_num_threads()
        if self.device == "cpu":
            torch.set_num_threads(1)
        try:
            with torch.no_grad():
                chunks = [self._chunk(self._batch(per_array(lambda v, i=i: v[i : i + block], raw)),
                                      noise[i : i + block].to(self.device))
                          for i in range(0, len(noise), block)]
        finally:
            torch.set_num_threads(threads)
        return self.postprocessor(torch.cat(chunks)[:n]).float().cpu().numpy()

    def _batch(self, raw: dict[str, np.ndarray]) -> dict:
        """One block of observations as the model takes them: each step's frame as LeRobot's eval
        builds it (preprocess_observation, "task", the saved preprocessor), steps stacked on axis 1."""
        if self.n_obs_steps == 1:
            return self._frame(raw)
        frames = [self._frame(per_array(lambda v, s=s: v[:, s], raw)) for s in range(self.n_obs_steps)]
        return {key: torch.stack([f[key] for f in frames], dim=1) for key in frames[0]
                if isinstance(frames[0][key], torch.Tensor)}

    def _frame(self, raw: dict[str, np.ndarray]) -> dict:
        from lerobot.envs.utils import preprocess_observation
        from lerobot.utils.constants import ACTION

        tensors = preprocess_observation(raw)
        self._check_features(tensors)
        tensors["task"] = [self.instruction] * len(next(iter(tensors.values())))
        frame = self.preprocessor(tensors)
        frame.pop(ACTION, None)  # as select_action does
        return frame

    def _check_features(self, tensors: dict[str, torch.Tensor]) -> None:
        """One-line UserError unless the observation has every input feature, in its shape."""
        given = {k: tuple(v.shape[1:]) for k, v in tensors.items()}
        wanted = {k: tuple(f.shape) for k, f in self.cfg.input_features.items()
                  if "empty_camera" not in k}  # VLAs fill these themselves
        if any(given.get(k) != shape for k, shape in wanted.items()):
            raise UserError(f"policy {self.name!r}: the env's observations give {given} after LeRobot's "
                            f"preprocess_observation; the policy's input features are {wanted}")


@contextlib.contextmanager
def _backbone_named(cfg, path: Path):
    """A one-line UserError where the backbone a VLA config names is neither a folder nor offline cached
    (an OSError, raised as it is or, from a processor step, as the cause of LeRobot's ValueError)."""
    try:
        yield
    except (OSError, ValueError) as error:
        missing = error if isinstance(error, OSError) else error.__cause__
        if not isinstance(missing, OSError):
            raise
        backbone = backbone_name(cfg, path)
        raise UserError(f"{path}: the {cfg.type} checkpoint needs the backbone {backbone!r} on disk, and it "
                        f"is not there ({str(missing).splitlines()[0]}); download it where a network is "
                        f"(`hf download {backbone}`, into the Hugging Face cache, ~/.cache/huggingface) or "
                        "set \"vlm_model_name\" in its config.json to a local folder") from None


def backbone_name(cfg, path: Path) -> str:
    """What a VLA reads besides its folder: SmolVLA's `vlm_model_name`, else the tokenizer its saved
    preprocessor names (pi0's and pi0.5's, PaliGemma's)."""
    if getattr(cfg, "vlm_model_name", None):
        return cfg.vlm_model_name
    steps = json.loads((path / "policy_preprocessor.json").read_text()).get("steps", [])
    named = [step.get("config", {}).get("tokenizer_name") for step in steps
             if step.get("registry_name") == "tokenizer_processor"]
    return next(filter(None, named), "its backbone")


def files_digest(path: Path) -> str:
    """sha256 of the config, weights and processor files, and of every file in a folder inside (a
    backbone the checkpoint carries)."""
    digest = hashlib.sha256()
    top = sorted([*path.glob("policy_*processor*"), path / "config.json", path / "model.safetensors"])
    inside = sorted(p for p in path.rglob("*") if p.is_file() and p.parent != path)
    for file in top + inside:
        digest.update(str(file.relative_to(path)).encode() + file.read_bytes())
    return digest.hexdigest()[:16]


def per_array(fn, obs: dict) -> dict:
    """`fn` applied to every array of a dict of arrays, or of such dicts (LeRobot's `pixels` cameras)."""
    return {k: per_array(fn, v) if isinstance(v, dict) else fn(v) for k, v in obs.items()}

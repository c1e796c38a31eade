"""What every LeRobot checkpoint adapter shares: the folder's checks, loading the model and its
saved processors, observations as LeRobot's eval loop builds them, and fixed blocks of rows."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
from collections.abc import Collection
from pathlib import Path

import numpy as np
import torch

from goldenticket.errors import UserError
from goldenticket.policies.folder import read_json, shown
from goldenticket.policies.numerics import BLOCK

PROCESSORS = ("policy_preprocessor.json", "policy_postprocessor.json")  # the pipelines LeRobot loads
REQUIRED = ("config.json", "model.safetensors", *PROCESSORS)
STEERED = ("diffusion", "smolvla", "pi0", "pi05")  # policy types whose initial noise can be passed
NOISE_FREE = ("act", "vqbet", "tdmpc", "gaussian_actor", "pi0_fast")  # regress or decode actions
INSTALL = "install it as README's \"LeRobot\" section says (a Python 3.12 venv with lerobot 0.6.1)"
OVERRIDABLE = ("n_action_steps",)  # config settings changed at eval time (lerobot-eval's --policy.KEY=VALUE)


def is_checkpoint(path: Path) -> bool:
    """A folder LeRobot wrote: one with policy_preprocessor*.json, or whose config.json has a "type"."""
    if not path.is_dir():
        return False
    if any(path.glob("policy_preprocessor*.json")):
        return True
    try:
        return "type" in json.loads((path / "config.json").read_text())
    except (OSError, ValueError, TypeError, RecursionError):
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


def check_pipeline(pipeline, where: str, registered: Collection[str], files: Collection[str],
                   needed: Collection[str] = ()) -> None:
    """A one-line UserError naming `where` and the step unless `pipeline` (a processor JSON's value) is a
    list of steps each named by a "registry_name" among `registered` (never by a "class", an import
    path LeRobot would import and call), with an object as its "config", its "state_file" (if any)
    one of `files` (the names of the checkpoint's files) and every step of `needed` among them."""
    steps = pipeline.get("steps") if isinstance(pipeline, dict) else None
    if not isinstance(steps, list):
        raise UserError(f'{where}: not a LeRobot processor pipeline (a JSON object with a "steps" list)')
    for i, step in enumerate(steps):
        if not isinstance(step, dict):
            raise UserError(f"{where}: step {i} is not a JSON object")
        if "class" in step:
            raise UserError(f"{where}: step {i} names the import path {shown(step['class'])}; goldenticket "
                            'loads only the processor steps LeRobot registers, named by "registry_name"')
        if "registry_name" not in step:
            raise UserError(f'{where}: step {i} names no "registry_name"')
        if not (isinstance(step["registry_name"], str) and step["registry_name"] in registered):
            raise UserError(f"{where}: step {i} {shown(step['registry_name'])} is no processor step LeRobot "
                            "registers")
        if not isinstance(step.get("config", {}), dict):
            raise UserError(f"{where}: step {i}'s config is not a JSON object")
        if "state_file" in step and not (isinstance(step["state_file"], str) and step["state_file"] in files):
            raise UserError(f"{where}: step {i}'s state_file {shown(step['state_file'])} is no file in the "
                            "checkpoint")
    names = {step["registry_name"] for step in steps}
    if missing := [name for name in needed if name not in names]:
        raise UserError(f"{where}: no {missing[0]!r} step, whose settings goldenticket sets (lerobot-train "
                        "writes one)")


def check_processors(path: Path, registered: Collection[str], needed: Collection[str] = ()) -> None:
    """`check_pipeline` on the checkpoint's preprocessor (which must have the steps `needed`) and
    postprocessor, before LeRobot reads them."""
    files = {file.name for file in path.iterdir() if file.is_file()}
    for name, steps in zip(PROCESSORS, (needed, ()), strict=True):
        check_pipeline(read_json(path / name), str(path / name), registered, files, steps)


def lerobot_steps() -> set[str]:
    """The registry names of the processor steps LeRobot itself registers (in its own modules)."""
    from lerobot.processor import ProcessorStepRegistry

    return {name for name in ProcessorStepRegistry.list()
            if ProcessorStepRegistry.get(name).__module__.startswith("lerobot.")}


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
    (`noise_shape`), how one block of rows becomes action chunks (`_chunk`), how many actions a call
    can execute (`_most_actions`) and which camera frames the model takes (`_check_cameras`);
    `steps` overrides the config's denoising step count (SmolVLA's `num_steps`, the others'
    `num_inference_steps`), `rename_map` maps the env's observation keys to the policy's and
    `overrides` change settings of its config (OVERRIDABLE), as `lerobot-eval` takes them."""

    def __init__(self, path: str | Path, steps: int | None = None, name: str | None = None,
                 device: str = "cpu", rename_map: dict | None = None, overrides: dict | None = None):
        self.path, self.steps, self.device = Path(path), steps, device
        self.rename_map, self._overrides = checked_rename_map(rename_map or {}), overrides or {}
        checked_config(self.path)
        config_class, policy_class, processors = lerobot_modules()
        cfg = config_class.from_pretrained(self.path)
        cfg.device = device
        self.overrides = self._overridden(cfg, self._overrides)
        overrides = {"device_processor": {"device": device}} | self._backbone_inside(cfg)
        if self.rename_map:
            overrides["rename_observations_processor"] = {"rename_map": self.rename_map}
        check_processors(self.path, lerobot_steps(), needed=overrides)
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

    def _most_actions(self, cfg) -> int:
        """The most actions one call can execute: the chunk the model predicts."""
        return cfg.chunk_size

    def _overridden(self, cfg, overrides: dict) -> dict:
        """`overrides` that change `cfg`, set in it; a one-line UserError for a setting not in
        OVERRIDABLE or a value the model cannot take."""
        for key, value in overrides.items():
            if key not in OVERRIDABLE:
                raise UserError(f"policy_override {key}: goldenticket changes {', '.join(OVERRIDABLE)} of a "
                                "LeRobot checkpoint")
            most = self._most_actions(cfg)
            if not (type(value) is int and 1 <= value <= most):
                raise UserError(f"policy_override n_action_steps must be an integer from 1 to {most} (the "
                                f"actions {self.path}'s model predicts per call), got {value!r}")
        changed = {key: value for key, value in overrides.items() if getattr(cfg, key) != value}
        for key, value in changed.items():
            setattr(cfg, key, value)
        return changed

    def _backbone_inside(self, cfg) -> dict:
        """A VLA whose `vlm_model_name` is a folder inside the checkpoint (a relative name) reads its
        backbone, and its tokenizer, from there; the processor overrides that say so."""
        name = getattr(cfg, "vlm_model_name", None)
        if not (name and (self.path / name).is_dir()):
            return {}
        cfg.vlm_model_name = str(self.path / name)
        return {"tokenizer_processor": {"tokenizer_name": cfg.vlm_model_name}}

    def __reduce__(self):  # worker processes load the folder again
        return (type(self), (self.path, self.steps, self.name, self.device, self.rename_map, self._overrides),
                {"instruction": self.instruction})

    def __copy__(self) -> LeRobotPolicy:  # in this process: the same model
        clone = object.__new__(type(self))
        clone.__dict__.update(self.__dict__)
        return clone

    def fingerprint(self) -> str:
        """Hash of the folder's config, weights and processor files, the denoising step count and each
        setting overridden (`-n_action_steps10`)."""
        changed = "".join(f"-{key}{value}" for key, value in sorted(self.overrides.items()))
        return f"lerobot-{self._digest}-steps{self.denoising_steps}{changed}"

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
        self.check_observations({key: tuple(value.shape[1:]) for key, value in tensors.items()})
        tensors["task"] = [self.instruction] * len(next(iter(tensors.values())))
        frame = self.preprocessor(tensors)
        frame.pop(ACTION, None)  # as select_action does
        return frame

    def check_observations(self, given: dict[str, tuple[int, ...]]) -> None:
        """One-line UserError unless observations of these keys and shapes (as LeRobot's
        `preprocess_observation` names them, before `rename_map`) are what `lerobot-eval` would run the
        policy on: the cameras' keys as LeRobot checks them (`validate_visual_features_consistency`,
        after `rename_map`), the frames the model takes (`_check_cameras`), and every other input
        feature in its shape."""
        from lerobot.configs.types import FeatureType, PolicyFeature
        from lerobot.policies.utils import validate_visual_features_consistency
        from lerobot.utils.constants import OBS_IMAGE

        given = {self.rename_map.get(key, key): shape for key, shape in given.items()}
        cameras = {key: shape for key, shape in given.items() if key.startswith(OBS_IMAGE)}
        try:
            validate_visual_features_consistency(
                self.cfg, {key: PolicyFeature(FeatureType.VISUAL, shape) for key, shape in cameras.items()})
        except ValueError:
            renamed = " (after rename_map)" if self.rename_map else ""
            raise UserError(f"policy {self.name!r}: the env's cameras {sorted(cameras)}{renamed} and the "
                            f"policy's input features are {sorted(self.cfg.image_features)}: neither holds "
                            "the other (LeRobot's check); map the env's keys to the policy's with rename_map "
                            "(--rename-map ENV_KEY=POLICY_KEY)") from None
        self._check_cameras(cameras)
        wanted = {key: tuple(f.shape) for key, f in self.cfg.input_features.items()
                  if key not in self.cfg.image_features}
        if any(given.get(key) != shape for key, shape in wanted.items()):
            others = {key: shape for key, shape in given.items() if key not in cameras}
            raise UserError(f"policy {self.name!r}: the env's observations give {others} after LeRobot's "
                            f"preprocess_observation; the policy's input features are {wanted}")

    def _check_cameras(self, cameras: dict[str, tuple[int, ...]]) -> None:
        """The frames of every size pass: SmolVLA, pi0 and pi0.5 resize them (with padding) themselves."""


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


def checked_rename_map(rename_map: dict) -> dict:
    """`rename_map` if it maps observation keys (strings) to keys (strings); a one-line UserError if not."""
    if not all(isinstance(key, str) and isinstance(value, str) for key, value in rename_map.items()):
        raise UserError(f"rename_map maps an env's observation key to the policy's (strings), got "
                        f"{rename_map}")
    return rename_map


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

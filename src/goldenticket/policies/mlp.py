"""Flow-matching and DDIM policies on one MLP denoiser, saved as safetensors + JSON config."""

from __future__ import annotations

import copy
import json
import math
from dataclasses import MISSING, asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save
from torch import nn
from torch.nn import functional

from goldenticket.errors import UserError
from goldenticket.files import write_atomic
from goldenticket.policies.folder import mismatch, planned_shapes, read_json, shown
from goldenticket.policies.numerics import float64, in_blocks, on_grid, state_hash

KINDS = ("flow", "ddim")


@dataclass
class PolicyConfig:
    """Everything needed to rebuild a policy besides its weights."""

    name: str
    kind: str  # "flow" (Euler, t=1 noise -> t=0 action) or "ddim" (eta=0, epsilon prediction)
    obs_dim: int
    action_dim: int
    horizon: int = 8
    n_exec: int = 4
    hidden: int = 256
    layers: int = 4
    steps: int = 10  # Euler steps (flow) or DDIM steps (ddim)
    train_timesteps: int = 100  # DDIM's discrete training schedule
    tasks: list[str] | None = None  # multi-task: the network also sees a one-hot over these tasks
    image_size: int | None = None  # sees {"pixels": uint8 [B, S, S, 3], "agent_pos": [B, obs_dim]}


MAX_TASKS = 1000


def _integer(low: int, high: int, nullable: bool = False):
    """A field's check: an integer (a bool is none) in low..high, or null where `nullable`."""
    def accepts(value) -> bool:
        return (nullable and value is None) or (
            isinstance(value, int) and not isinstance(value, bool) and low <= value <= high)
    return accepts, ("null or " if nullable else "") + f"an integer in {low}..{high}"


def _task_names(value) -> bool:
    return value is None or (isinstance(value, list) and 0 < len(value) <= MAX_TASKS
                             and all(isinstance(name, str) and name for name in value)
                             and len(set(value)) == len(value))


FIELDS = {  # each field of a PolicyConfig: what it accepts and how to say so; the integers' ranges reach
    # past any policy made here and stop short of a network no machine builds or a call none runs
    "name": (lambda value: isinstance(value, str) and value != "", "a non-empty string"),
    "kind": (lambda value: value in KINDS, f"one of {', '.join(KINDS)}"),
    "obs_dim": _integer(1, 4096), "action_dim": _integer(1, 64), "horizon": _integer(1, 256),
    "n_exec": _integer(1, 256), "hidden": _integer(1, 8192), "layers": _integer(1, 64),
    "steps": _integer(1, 1000), "train_timesteps": _integer(2, 10_000),
    "tasks": (_task_names, f"null or a list of distinct task names (at most {MAX_TASKS})"),
    "image_size": _integer(8, 512, nullable=True),
}


def check_config(values: dict, where: str) -> PolicyConfig:
    """The PolicyConfig of `values` (a config.json's fields), once each is checked as an option is:
    no unknown or missing field, each of its type (a bool is no integer) and range, the fields
    together, and the size of the network they describe (nothing is built); else a one-line UserError
    naming `where` and the field."""
    if unknown := sorted(set(values) - FIELDS.keys()):
        raise UserError(f"{where}: unknown field {', '.join(unknown)}; a policy config.json has "
                        f"{', '.join(FIELDS)}")
    required = [f.name for f in fields(PolicyConfig) if f.default is MISSING]
    if missing := [name for name in required if name not in values]:
        raise UserError(f"{where}: no {', '.join(missing)} (a policy config.json needs "
                        f"{', '.join(required)})")
    for name, value in values.items():
        accepts, wanted = FIELDS[name]
        if not accepts(value):
            raise UserError(f"{where}: {name} must be {wanted}, got {shown(value)}")
    cfg = PolicyConfig(**values)
    if cfg.n_exec > cfg.horizon:
        raise UserError(f"{where}: n_exec {cfg.n_exec} cannot exceed horizon {cfg.horizon}")
    if cfg.kind == "ddim" and cfg.steps > cfg.train_timesteps:
        raise UserError(f"{where}: steps {cfg.steps} exceeds train_timesteps {cfg.train_timesteps} (DDIM "
                        "steps are trained timesteps)")
    if cfg.image_size and cfg.tasks:
        raise UserError(f"{where}: an image policy (image_size) cannot also be multi-task (tasks)")
    planned_shapes(lambda: Denoiser(cfg), where)
    return cfg


def _time_embedding(t: torch.Tensor, dim: int = 32) -> torch.Tensor:
    freqs = torch.exp(torch.arange(dim // 2, dtype=t.dtype) * (-math.log(1000.0) / (dim // 2)))
    angles = 1000.0 * t[:, None] * freqs[None]
    return torch.cat([angles.sin(), angles.cos()], dim=1)


FEATURES = 64  # what the image encoder makes of a frame


class ConvEncoder(nn.Module):
    """RGB frames [B, S, S, 3] with values 0..255 -> [B, FEATURES]: three 3 x 3 convolutions of
    stride 2 with GELU, then one linear layer on the whole map (where things are matters)."""

    CHANNELS = (3, 16, 32, 32)

    def __init__(self, size: int):
        super().__init__()
        pairs = zip(self.CHANNELS[:-1], self.CHANNELS[1:], strict=True)
        self.convs = nn.ModuleList(nn.Conv2d(a, b, 3, stride=2, padding=1) for a, b in pairs)
        self.out = nn.Linear(self.CHANNELS[-1] * math.ceil(size / 8) ** 2, FEATURES)

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        x = pixels.permute(0, 3, 1, 2) / 255 - 0.5
        for conv in self.convs:
            x = functional.gelu(conv(x))
        return self.out(x.flatten(1))


class Denoiser(nn.Module):
    """MLP on [normalised obs, noisy chunk, time embedding] -> chunk-shaped output; an image
    policy's obs is its frame's encoding followed by its normalised `agent_pos`."""

    def __init__(self, cfg: PolicyConfig):
        super().__init__()
        width = cfg.horizon * cfg.action_dim
        self.encoder = ConvEncoder(cfg.image_size) if cfg.image_size else None
        features = FEATURES if cfg.image_size else 0
        dims = [features + cfg.obs_dim + len(cfg.tasks or ()) + width + 32] + [cfg.hidden] * cfg.layers
        blocks: list[nn.Module] = []
        for d_in, d_out in zip(dims[:-1], dims[1:], strict=True):
            blocks += [nn.Linear(d_in, d_out), nn.GELU()]
        self.net = nn.Sequential(*blocks, nn.Linear(cfg.hidden, width))
        self.register_buffer("obs_mean", torch.zeros(cfg.obs_dim))
        self.register_buffer("obs_std", torch.ones(cfg.obs_dim))
        self.register_buffer("act_low", -torch.ones(cfg.action_dim))
        self.register_buffer("act_high", torch.ones(cfg.action_dim))

    def forward(self, obs_n: torch.Tensor, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        flat = torch.cat([obs_n, x.flatten(1), _time_embedding(t)], dim=1)
        return self.net(flat).view_as(x)

    def normalise_obs(self, obs: torch.Tensor | dict[str, torch.Tensor]) -> torch.Tensor:
        """Observations standardised; columns past obs_dim (a task one-hot) pass unchanged; a
        frame is encoded."""
        if isinstance(obs, dict):
            return torch.cat([self.encoder(obs["pixels"]), self.normalise_obs(obs["agent_pos"])], dim=1)
        n = len(self.obs_mean)
        if obs.shape[1] == n:
            return (obs - self.obs_mean) / self.obs_std
        return torch.cat([(obs[:, :n] - self.obs_mean) / self.obs_std, obs[:, n:]], dim=1)

    def normalise_actions(self, actions: torch.Tensor) -> torch.Tensor:
        return 2 * (actions - self.act_low) / (self.act_high - self.act_low) - 1

    def denormalise_actions(self, x: torch.Tensor) -> torch.Tensor:
        return (x.clamp(-1, 1) + 1) / 2 * (self.act_high - self.act_low) + self.act_low


def ddim_alpha_bar(t: torch.Tensor) -> torch.Tensor:
    """Cosine schedule: cumulative signal fraction at continuous time t in [0, 1]."""
    return torch.cos((t + 0.008) / 1.008 * math.pi / 2) ** 2


class Float64Denoiser:
    """The denoiser in float64 for a fixed list of times, arranged for speed.

    The first layer sees [observation, noisy chunk, time embedding]: the observation's share is
    computed once per call (`condition`), the time embedding's once per time here; each denoising
    step then multiplies only the chunk.
    """

    def __init__(self, model: Denoiser, times: torch.Tensor):
        """`model`: the float64 copy of the denoiser."""
        linears = [m for m in model.net if isinstance(m, nn.Linear)]
        first, width = linears[0], model.net[-1].out_features
        n_obs = first.in_features - width - 32
        self.w_obs = first.weight[:, :n_obs].contiguous().T  # transposed views, as nn.Linear uses them
        self.w_chunk = first.weight[:, n_obs : n_obs + width].contiguous().T
        embedded = _time_embedding(times) @ first.weight[:, n_obs + width :].T
        self.time_bias = [row + first.bias for row in embedded]
        self.layers = [(m.weight.detach().T, m.bias.detach()) for m in linears[1:]]

    def condition(self, obs_n: torch.Tensor) -> torch.Tensor:
        """The observation's share of the first layer, for every step of one call."""
        return obs_n @ self.w_obs

    def __call__(self, condition: torch.Tensor, x: torch.Tensor, step: int) -> torch.Tensor:
        """The network's output at the step-th time, for chunks x [B, H, A]."""
        h = torch.addmm(condition + self.time_bias[step], x.flatten(1), self.w_chunk)
        for weight, bias in self.layers:
            h = torch.addmm(bias, _gelu(h), weight)
        return h.view_as(x)


def _gelu(h: torch.Tensor) -> torch.Tensor:
    """Exact GELU, x * Phi(x), in place."""
    phi = torch.erf(h * SQRT_HALF).add_(1)
    return h.mul_(0.5).mul_(phi)


SQRT_HALF = math.sqrt(0.5)


class MLPPolicy:
    """A frozen denoising policy; `act` is deterministic given (obs, noise), on any x86-64 CPU.

    `model` holds the float32 weights (trained, saved, hashed); inference runs on a float64 copy.
    A multi-task policy (`cfg.tasks`) acts once `conditioned` on one of its tasks.
    """

    task: str | None = None  # the task a multi-task policy is conditioned on

    def __init__(self, cfg: PolicyConfig, model: Denoiser | None = None):
        check_config(asdict(cfg), f"policy {cfg.name!r}")
        self.cfg = cfg
        self.model = (model or Denoiser(cfg)).eval()
        self._scale = copy.deepcopy(self.model).double()  # float64: (de)normalisation and the network
        self._times = self._flow_times() if cfg.kind == "flow" else self._ddim_times()
        self._net = Float64Denoiser(self._scale, self._times)

    name = property(lambda self: self.cfg.name)
    n_exec = property(lambda self: self.cfg.n_exec)
    noise_shape = property(lambda self: (self.cfg.horizon, self.cfg.action_dim))
    tasks = property(lambda self: self.cfg.tasks)

    def conditioned(self, task: str) -> MLPPolicy:
        """This multi-task policy acting on `task` (one of `cfg.tasks`); the weights are shared."""
        if task not in (self.cfg.tasks or ()):
            raise UserError(f"policy {self.name!r} is not trained for task {task!r}; "
                            f"its tasks: {', '.join(self.cfg.tasks or ['none (single-task)'])}")
        policy = copy.copy(self)
        policy.task = task
        return policy

    def act(self, obs: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """Same actions on every CPU: float64 inference in fixed blocks, rounded to a grid
        (`policies/numerics.py`)."""
        denoise = self._flow if self.cfg.kind == "flow" else self._ddim
        x = in_blocks(lambda rows, x: denoise(self._scale.normalise_obs(rows), x), self._inputs(obs), noise)
        return on_grid(self._scale.denormalise_actions(x)[:, : self.cfg.n_exec])

    def _inputs(self, obs) -> torch.Tensor | dict[str, torch.Tensor]:
        """float64 observations, with the task's one-hot for a multi-task policy."""
        if self.cfg.image_size:
            return float64(self._checked_frames(obs))
        if isinstance(obs, dict):
            raise UserError(f"policy {self.name!r} sees state vectors [B, {self.cfg.obs_dim}], got "
                            f"observations with keys {sorted(obs)} (a camera task needs an image policy)")
        obs = float64(obs)
        if obs.ndim != 2 or obs.shape[1] != self.cfg.obs_dim:
            raise UserError(f"policy {self.name!r} sees state vectors [B, {self.cfg.obs_dim}], got "
                            f"{list(obs.shape)}: it was trained on another task's observations")
        if not self.cfg.tasks:
            return obs
        if self.task is None:
            raise UserError(f"policy {self.name!r} is multi-task: condition it on one of its tasks "
                            "first (policy.conditioned(task))")
        one_hot = torch.zeros(len(obs), len(self.cfg.tasks), dtype=torch.float64)
        one_hot[:, self.cfg.tasks.index(self.task)] = 1.0
        return torch.cat([obs, one_hot], dim=1)

    def _checked_frames(self, obs) -> dict[str, np.ndarray]:
        """An image policy's observations as its contract says, else a one-line UserError."""
        size, n = self.cfg.image_size, self.cfg.obs_dim
        if not (isinstance(obs, dict) and {"pixels", "agent_pos"} <= obs.keys()):
            got = sorted(obs) if isinstance(obs, dict) else type(obs).__name__
            raise UserError(f"policy {self.name!r} sees images: observations must be dicts with 'pixels' "
                            f"and 'agent_pos', got {got}")
        pixels, agent_pos = np.asarray(obs["pixels"]), np.asarray(obs["agent_pos"])
        if pixels.dtype != np.uint8 or pixels.shape[1:] != (size, size, 3):
            raise UserError(f"policy {self.name!r}: 'pixels' must be uint8 [B, {size}, {size}, 3], "
                            f"got {pixels.dtype} {list(pixels.shape)}")
        if agent_pos.shape != (len(pixels), n):
            raise UserError(f"policy {self.name!r}: 'agent_pos' must be [B, {n}] beside {len(pixels)} "
                            f"frames, got {list(agent_pos.shape)}")
        return {"pixels": pixels, "agent_pos": agent_pos}

    def _flow_times(self) -> torch.Tensor:
        """Euler steps from t=1 (noise) to t=0 (action): the time each step starts at."""
        return torch.linspace(1.0, 0.0, self.cfg.steps + 1, dtype=torch.float64)[:-1]

    def _flow(self, obs_n: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        condition = self._net.condition(obs_n)
        dts = self._times.diff(append=self._times.new_zeros(1))  # each step's t_next - t
        for step, dt in enumerate(dts):
            x = x + dt * self._net(condition, x, step)
        return x

    def _ddim_times(self) -> torch.Tensor:
        """Deterministic DDIM on "leading" training timesteps (steps-1)*T/steps, ..., T/steps, 0,
        ending on the clean sample. The terminal timestep is never used: its alpha_bar is ~0,
        which would make x0 = (x - eps) / sqrt(alpha_bar) rounding error."""
        T = self.cfg.train_timesteps
        steps = torch.arange(self.cfg.steps - 1, -1, -1, dtype=torch.float64)
        return steps * (T // self.cfg.steps) / (T - 1)

    def _ddim(self, obs_n: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        condition = self._net.condition(obs_n)
        alphas = [ddim_alpha_bar(t) for t in self._times] + [torch.tensor(1.0, dtype=torch.float64)]
        for step, (a, a_next) in enumerate(zip(alphas[:-1], alphas[1:], strict=True)):
            eps = self._net(condition, x, step)
            x0 = ((x - (1 - a).sqrt() * eps) / a.sqrt()).clamp(-1.5, 1.5)
            x = a_next.sqrt() * x0 + (1 - a_next).sqrt() * eps
        return x

    def fingerprint(self) -> str:
        """What a ticket is found for: the weights hash and the denoising step count."""
        return f"{self.weights_hash()}@{self.cfg.steps}"

    def weights_hash(self) -> str:
        return state_hash(self.model.state_dict())

    def save(self, directory: Path) -> None:
        write_atomic(directory / "model.safetensors", save(self.model.state_dict()))
        write_atomic(directory / "config.json", json.dumps(asdict(self.cfg), indent=2) + "\n")

    @classmethod
    def load(cls, directory: Path) -> MLPPolicy:
        """The policy in `directory` (config.json + model.safetensors): every field of the config and
        every tensor's name and shape checked before the network is built; a one-line UserError
        naming the file otherwise."""
        config = directory / "config.json"
        values = read_json(config)
        if not isinstance(values, dict):
            raise UserError(f"{config}: not a policy config (a JSON object of its fields)")
        cfg = check_config(values, str(config))
        wanted = planned_shapes(lambda: Denoiser(cfg), str(config))
        tensors = _tensors(directory / "model.safetensors", wanted)
        model = Denoiser(cfg)
        model.load_state_dict(tensors)
        return cls(cfg, model)


def _tensors(weights: Path, wanted: dict[str, tuple[int, ...]]) -> dict[str, torch.Tensor]:
    """The tensors of a safetensors file, once their names and shapes are the `wanted` ones (read from
    its header first); a one-line UserError naming the file otherwise."""
    try:
        with safe_open(str(weights), "pt") as file:
            given = {key: tuple(file.get_slice(key).get_shape()) for key in file.keys()}  # noqa: SIM118 (no __iter__)
            if problem := mismatch(given, wanted, "the network its config.json describes"):
                raise UserError(f"{weights}: {problem}")
            return {key: file.get_tensor(key) for key in given}
    except SafetensorError as exc:
        raise UserError(f"{weights}: not a valid safetensors file ({exc})") from None
    except OSError as exc:
        raise UserError(f"cannot read {weights}: {exc.strerror}") from None

"""DPPO checkpoints as NoisePolicies: the state-based diffusion MLPs of DPPO (Ren et al., "Diffusion
Policy Policy Optimization", arXiv:2409.00588; github.com/irom-princeton/dppo), pre-trained or
fine-tuned.

A DPPO checkpoint folder holds one checkpoint `*.pt` as DPPO's agents save it (pre-training:
{"epoch", "model", "ema"}; fine-tuning: {"itr", "model"}), the run's hydra config `*.yaml` (as
written, with `${key}` and `${eval:'...'}` interpolations, or resolved) and DPPO's
`normalization.npz` (obs_min, obs_max, action_min, action_max). The path of a `.pt` file names one
of several checkpoints in a folder.

The ticket is the initial noise x_T of shape (horizon_steps, action_dim), what DPPO draws with
`torch.randn` at every call. Sampling is DPPO's DDIM with eta = 0 (its clipping included); a config
that samples with DDPM runs DDIM over every trained timestep, and `DIR@N` runs N steps, as DPPO runs
`use_ddim: True, ddim_steps: N`. Inference runs in float64 on fixed blocks of rows, rounded to a grid
(`numerics.py`): the same actions on every x86-64 CPU, each row's independent of the others.
"""

from __future__ import annotations

import ast
import copy
import hashlib
import io
import json
import math
import operator
import re
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from goldenticket.errors import UserError
from goldenticket.files import write_atomic
from goldenticket.policies.folder import mismatch, planned_shapes, shown
from goldenticket.policies.numerics import float64, in_blocks, on_grid

SAMPLERS = ("DiffusionModel", "DiffusionEval", "VPGDiffusion", "PPODiffusion")  # model._target_ classes
NETWORK = "DiffusionMLP"  # model.network._target_ (model.actor._target_ in fine-tuning configs)
NORMALIZATION = "normalization.npz"
ACTIVATIONS = {"ReLU": nn.ReLU, "ELU": nn.ELU, "GELU": nn.GELU, "Tanh": nn.Tanh, "Mish": nn.Mish,
               "Identity": nn.Identity, "Softplus": nn.Softplus}


@dataclass(frozen=True)
class NetworkSpec:
    """DiffusionMLP's arguments, with DPPO's defaults."""

    action_dim: int
    horizon_steps: int
    cond_dim: int  # obs_dim * cond_steps
    time_dim: int = 16
    mlp_dims: tuple[int, ...] = (256, 256)
    cond_mlp_dims: tuple[int, ...] | None = None
    activation_type: str = "Mish"
    out_activation_type: str = "Identity"
    use_layernorm: bool = False
    residual_style: bool = False


class DiffusionMLP(nn.Module):
    """DPPO's DiffusionMLP, with its parameter names: epsilon for chunks x [B, H, A] at timesteps t [B]
    given flattened normalised observations [B, cond_dim], from [chunk, time embedding, observations
    (through cond_mlp where the spec has one)]."""

    def __init__(self, spec: NetworkSpec):
        super().__init__()
        self.spec = spec
        width, td = spec.horizon_steps * spec.action_dim, spec.time_dim
        self.time_embedding = nn.Sequential(SinusoidalEmbedding(td), nn.Linear(td, 2 * td), nn.Mish(),
                                            nn.Linear(2 * td, td))
        self.cond_mlp = None
        cond_width = spec.cond_dim
        if spec.cond_mlp_dims is not None:
            self.cond_mlp = MLP([spec.cond_dim, *spec.cond_mlp_dims], spec.activation_type, "Identity")
            cond_width = spec.cond_mlp_dims[-1]
        head = ResidualMLP if spec.residual_style else MLP
        self.mlp_mean = head([width + td + cond_width, *spec.mlp_dims, width], spec.activation_type,
                             spec.out_activation_type, spec.use_layernorm)

    def forward(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        state = cond if self.cond_mlp is None else self.cond_mlp(cond)
        return self.mlp_mean(torch.cat([x.flatten(1), self.time_embedding(t), state], dim=1)).view_as(x)


class SinusoidalEmbedding(nn.Module):
    """Timesteps [B] -> [B, dim]: sines then cosines of t at frequencies 10000^(-i / (dim/2 - 1))."""

    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        half = self.dim // 2
        freqs = torch.exp(torch.arange(half, dtype=t.dtype) * (-math.log(10000) / (half - 1)))
        angles = t[:, None] * freqs[None]
        return torch.cat([angles.sin(), angles.cos()], dim=1)


class MLP(nn.Module):
    """DPPO's MLP: each layer `linear_1`, then `norm_1` (LayerNorm, not after the last layer) where
    asked, then `act_1` (the output activation after the last)."""

    def __init__(self, dims: list[int], activation: str, out_activation: str, layernorm: bool = False):
        super().__init__()
        last = len(dims) - 2
        self.moduleList = nn.ModuleList()
        for i, (d_in, d_out) in enumerate(zip(dims[:-1], dims[1:], strict=True)):
            layer = OrderedDict(linear_1=nn.Linear(d_in, d_out))
            if layernorm and i < last:
                layer["norm_1"] = nn.LayerNorm(d_out)
            layer["act_1"] = ACTIVATIONS[out_activation if i == last else activation]()
            self.moduleList.append(nn.Sequential(layer))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.moduleList:
            x = layer(x)
        return x


class ResidualMLP(nn.Module):
    """DPPO's residual MLP: a linear layer to the width dims[1], (len(dims) - 3) / 2 pre-activation
    residual blocks of that width, a linear layer out, then the output activation."""

    def __init__(self, dims: list[int], activation: str, out_activation: str, layernorm: bool = False):
        super().__init__()
        width = dims[1]
        blocks = [ResidualBlock(width, activation, layernorm) for _ in range((len(dims) - 3) // 2)]
        self.layers = nn.ModuleList([nn.Linear(dims[0], width), *blocks, nn.Linear(width, dims[-1]),
                                     ACTIVATIONS[out_activation]()])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers:
            x = layer(x)
        return x


class ResidualBlock(nn.Module):
    """x + l2(act(norm2(l1(act(norm1(x)))))), the norms where asked."""

    def __init__(self, width: int, activation: str, layernorm: bool):
        super().__init__()
        self.l1, self.l2 = nn.Linear(width, width), nn.Linear(width, width)
        self.act = ACTIVATIONS[activation]()
        self.norm1 = nn.LayerNorm(width, eps=1e-6) if layernorm else None
        self.norm2 = nn.LayerNorm(width, eps=1e-6) if layernorm else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x if self.norm1 is None else self.norm1(x)
        h = self.l1(self.act(h))
        h = h if self.norm2 is None else self.norm2(h)
        return x + self.l2(self.act(h))


def alphas_cumprod(denoising_steps: int) -> torch.Tensor:
    """alpha-bar_t for t = 0 .. T-1, in float32 as DPPO computes it: the cosine schedule (s = 0.008) on
    `np.linspace(0, T + 1, T + 1) / (T + 1)`, betas clipped to [0, 0.999], a float32 cumulative product."""
    T, s = denoising_steps, 0.008
    grid = [i * ((T + 1) / T) / (T + 1) for i in range(T)] + [1.0]
    f = [math.cos((u + s) / (1 + s) * math.pi * 0.5) ** 2 for u in grid]
    f = [v / f[0] for v in f]
    betas = [min(max(1 - b / a, 0.0), 0.999) for a, b in zip(f[:-1], f[1:], strict=True)]
    return torch.cumprod(1.0 - torch.tensor(betas, dtype=torch.float32), dim=0)


@dataclass(frozen=True)
class DPPOConfig:
    """What a DPPO config fixes for acting (defaults: DPPO's)."""

    network: NetworkSpec
    sampler: str  # model._target_'s class, one of SAMPLERS
    obs_dim: int
    cond_steps: int  # observations per call: the last cond_steps, oldest first
    act_steps: int  # actions executed per call
    denoising_steps: int  # trained timesteps T
    ddim_steps: int  # DDIM steps run: timesteps (N-1)r, ..., r, 0 with r = T // N
    ft_below: int  # the fine-tuned network (actor_ft) acts at timesteps t < ft_below
    denoised_clip_value: float | None
    eps_clip_value: float | None
    final_action_clip_value: float | None


_REQUIRED, _ABSENT = object(), object()
MAX_SIZE = 10_000  # the most any integer read (a width, a dimension, a step count) may be
MAX_LAYERS = 64  # widths in mlp_dims or cond_mlp_dims
MAX_INTERPOLATIONS = 10_000  # ${...} resolved in reading one config
MAX_EXPRESSION = 1000  # characters of one ${eval:'...'}, its references written in
MAX_DEPTH = 100  # nesting of its operations
MAX_NUMBER = 1e18  # magnitude of any number in it


class _Yaml:
    """A DPPO config file; `${key}` and `${eval:'arithmetic'}` are resolved in the values read."""

    def __init__(self, path: Path):
        import yaml

        self.path, self.interpolations = path, 0
        try:
            self.root = yaml.safe_load(path.read_text())
        except RecursionError:
            raise UserError(f"{path}: not a YAML file (nested too deeply)") from None
        except (yaml.YAMLError, ValueError) as exc:  # ValueError: an integer of too many digits, or no UTF-8
            raise UserError(f"{path}: not a YAML file ({str(exc).splitlines()[0]})") from None
        if not isinstance(self.root, dict):
            raise UserError(f"{path}: not a DPPO config (a YAML mapping with a `model` section)")

    def has(self, key: str) -> bool:
        return self._raw(key, _ABSENT) is not _ABSENT

    def get(self, key: str, default=_REQUIRED):
        return self._resolved(self._raw(key, default), key, 0)

    def integer(self, key: str, default=_REQUIRED, least: int = 1) -> int:
        value = self.get(key, default)
        if not (isinstance(value, int) and not isinstance(value, bool) and least <= value <= MAX_SIZE):
            raise UserError(f"{self.path}: {key} must be an integer in {least}..{MAX_SIZE}, got "
                            f"{shown(value)}")
        return value

    def number(self, key: str, default) -> float | None:
        value = self.get(key, default)
        try:
            number = None if value is None else float(value)  # YAML 1.1 reads 1e-4 as a string
        except (TypeError, ValueError, OverflowError):
            number = math.nan
        if number is not None and not math.isfinite(number):
            raise UserError(f"{self.path}: {key} must be a finite number or null, got {shown(value)}")
        return number

    def flag(self, key: str, default: bool) -> bool:
        value = self.get(key, default)
        if not isinstance(value, bool):
            raise UserError(f"{self.path}: {key} must be True or False, got {value!r}")
        return value

    def choice(self, key: str, default: str, choices) -> str:
        value = self.get(key, default)
        if not (isinstance(value, str) and value in choices):
            raise UserError(f"{self.path}: {key} is {shown(value)}; DPPO's DiffusionMLP takes "
                            f"{', '.join(choices)}")
        return value

    def dims(self, key: str, default) -> tuple[int, ...] | None:
        value = self.get(key, default)
        if value is None:
            return None
        widths = isinstance(value, list | tuple) and 0 < len(value) <= MAX_LAYERS
        if not (widths and all(isinstance(d, int) and not isinstance(d, bool) and 1 <= d <= MAX_SIZE
                               for d in value)):
            raise UserError(f"{self.path}: {key} must be a list of 1 to {MAX_LAYERS} layer widths in "
                            f"1..{MAX_SIZE}, got {shown(value)}")
        return tuple(value)

    def _raw(self, key: str, default, where: str | None = None):
        node = self.root
        for part in key.split("."):
            if not (isinstance(node, dict) and part in node):
                if default is not _REQUIRED:
                    return default
                if where:
                    raise UserError(f"{self.path}: {where} refers to ${{{key}}}, which the config does "
                                    "not set")
                raise UserError(f"{self.path}: no {key} (DPPO's configs set it)")
            node = node[part]
        return node

    def _resolved(self, value, key: str, depth: int):
        if isinstance(value, list):
            return [self._resolved(v, key, depth) for v in value]
        if not (isinstance(value, str) and "${" in value):
            return value
        if depth > 32:
            raise UserError(f"{self.path}: {key} interpolates itself")
        self.interpolations += 1
        if self.interpolations > MAX_INTERPOLATIONS:
            raise UserError(f"{self.path}: {key}: more than {MAX_INTERPOLATIONS} interpolations in reading "
                            "the config; write the values themselves")
        text = value.strip()
        if whole := re.fullmatch(r"\$\{\s*([\w.]+)\s*\}", text):
            return self._resolved(self._raw(whole[1], _REQUIRED, key), whole[1], depth + 1)
        if expr := re.fullmatch(r"""\$\{eval:\s*(['"])(.*)\1\s*\}""", text, re.S):
            code = re.sub(r"\$\{\s*([\w.]+)\s*\}", lambda ref: repr(self._resolved(
                self._raw(ref[1], _REQUIRED, key), ref[1], depth + 1)), expr[2])
            return _arithmetic(code, f"{self.path}: {key}: {value}")
        raise UserError(f"{self.path}: {key}: {value!r} needs an interpolation goldenticket does not resolve "
                        "(it resolves ${key} and ${eval:'arithmetic'}); write the value itself")


_OPERATORS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
              ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.USub: operator.neg,
              ast.UAdd: operator.pos}
_FUNCTIONS = {"round": round, "int": int, "float": float, "min": min, "max": max, "abs": abs}


class _OutOfBounds(Exception):
    """An expression past one of the bounds on its length, nesting or numbers; the message says which."""


def _arithmetic(code: str, where: str):
    """The value of `${eval:'...'}` where it is arithmetic (numbers, + - * / // %, round, int, float,
    min, max, abs), computed without running code from the file: at most MAX_EXPRESSION characters,
    nested at most MAX_DEPTH deep, every number within MAX_NUMBER; a one-line UserError otherwise."""

    def value(node, depth: int):
        if depth > MAX_DEPTH:
            raise _OutOfBounds(f"nested more than {MAX_DEPTH} deep")
        result = _operation(node, lambda child: value(child, depth + 1))
        if not abs(result) <= MAX_NUMBER:  # NaN and infinities too
            raise _OutOfBounds(f"a number past {MAX_NUMBER:g}")
        return result

    try:
        if len(code) > MAX_EXPRESSION:
            raise _OutOfBounds(f"longer than {MAX_EXPRESSION} characters, its references written in")
        return value(ast.parse(code, mode="eval").body, 0)
    except _OutOfBounds as exc:
        raise UserError(f"{where}: {exc}; write the value itself") from None
    except (SyntaxError, ValueError, TypeError, ArithmeticError, RecursionError, MemoryError):
        raise UserError(f"{where}: goldenticket evaluates only arithmetic here; write the value "
                        "itself") from None


def _operation(node, value):
    """One node of an arithmetic expression, its operands' values given by `value`; ValueError for
    anything else (round's digits only within 0..MAX_DEPTH)."""
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return node.value
    if isinstance(node, ast.BinOp) and type(node.op) in _OPERATORS:
        return _OPERATORS[type(node.op)](value(node.left), value(node.right))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _OPERATORS:
        return _OPERATORS[type(node.op)](value(node.operand))
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _FUNCTIONS
            and not node.keywords):
        args = [value(arg) for arg in node.args]
        if node.func.id == "round" and len(args) == 2 and not 0 <= args[1] <= MAX_DEPTH:
            raise ValueError
        return _FUNCTIONS[node.func.id](*args)
    raise ValueError


def read_config(path: Path, steps: int | None = None) -> DPPOConfig:
    """The acting settings of a DPPO config file; `steps` overrides the DDIM step count. One-line
    UserError for a model goldenticket does not run or a value missing or out of range."""
    cfg = _Yaml(path)
    target = str(cfg.get("model._target_"))
    sampler = target.rpartition(".")[2]
    if sampler not in SAMPLERS:
        raise UserError(f"{path}: model._target_ is {target!r}; goldenticket runs DPPO's "
                        f"{', '.join(SAMPLERS)} (a checkpoint fine-tuned by another method runs with DPPO's "
                        "eval config, model.diffusion.diffusion_eval.DiffusionEval)")
    net = "model.network" if cfg.has("model.network") else "model.actor"
    kind = str(cfg.get(f"{net}._target_"))
    if kind.rpartition(".")[2] != NETWORK:
        raise UserError(f"{path}: {net}._target_ is {kind!r}; goldenticket runs DPPO's state-based "
                        f"model.diffusion.mlp_diffusion.{NETWORK}, not its image or UNet networks")
    spec = NetworkSpec(
        action_dim=cfg.integer(f"{net}.action_dim"), horizon_steps=cfg.integer(f"{net}.horizon_steps"),
        cond_dim=cfg.integer(f"{net}.cond_dim"), time_dim=cfg.integer(f"{net}.time_dim", 16, least=4),
        mlp_dims=cfg.dims(f"{net}.mlp_dims", [256, 256]),
        cond_mlp_dims=cfg.dims(f"{net}.cond_mlp_dims", None),
        activation_type=cfg.choice(f"{net}.activation_type", "Mish", ACTIVATIONS),
        out_activation_type=cfg.choice(f"{net}.out_activation_type", "Identity", ACTIVATIONS),
        use_layernorm=cfg.flag(f"{net}.use_layernorm", False),
        residual_style=cfg.flag(f"{net}.residual_style", False))
    planned_shapes(lambda: DiffusionMLP(spec), f"{path}: {net}")
    if spec.residual_style and len(spec.mlp_dims) % 2 == 0:
        raise UserError(f"{path}: {net}.mlp_dims {list(spec.mlp_dims)}: a residual DiffusionMLP needs an odd "
                        "number of widths (a first layer and pairs of layers)")
    obs_dim, cond_steps = cfg.integer("model.obs_dim"), cfg.integer("cond_steps", 1)
    for key in ("action_dim", "horizon_steps"):
        if (value := cfg.integer(f"model.{key}")) != getattr(spec, key):
            raise UserError(f"{path}: model.{key} is {value} and {net}.{key} {getattr(spec, key)}; they "
                            "must agree")
    if spec.cond_dim != obs_dim * cond_steps:
        raise UserError(f"{path}: {net}.cond_dim is {spec.cond_dim}, not obs_dim * cond_steps = "
                        f"{obs_dim} * {cond_steps}")
    if not cfg.flag("model.predict_epsilon", True):
        raise UserError(f"{path}: model.predict_epsilon is False; DPPO's DDIM, which a ticket needs, "
                        "predicts epsilon")
    if cfg.get("model.ddim_discretize", "uniform") != "uniform":
        raise UserError(f"{path}: model.ddim_discretize must be 'uniform', DPPO's only one")
    T = cfg.integer("model.denoising_steps", 100)
    trained = cfg.integer("model.ddim_steps") if cfg.flag("model.use_ddim", False) else None
    ft = 0 if sampler == "DiffusionModel" else cfg.integer("model.ft_denoising_steps", 0, least=0)
    if ft > (trained or T):
        raise UserError(f"{path}: model.ft_denoising_steps {ft} exceeds the {trained or T} denoising steps")
    run = steps or trained or T
    if run > T:
        raise UserError(f"{path}: {run} DDIM steps, more than the {T} trained timesteps "
                        "(model.denoising_steps)")
    act_steps = cfg.integer("act_steps", spec.horizon_steps)
    if act_steps > spec.horizon_steps:
        raise UserError(f"{path}: act_steps {act_steps} exceeds horizon_steps {spec.horizon_steps}")
    return DPPOConfig(
        network=spec, sampler=sampler, obs_dim=obs_dim, cond_steps=cond_steps, act_steps=act_steps,
        denoising_steps=T, ddim_steps=run, ft_below=ft * (T // trained if trained else 1),
        denoised_clip_value=cfg.number("model.denoised_clip_value", 1.0),
        eps_clip_value=cfg.number("model.eps_clip_value", None),
        final_action_clip_value=cfg.number("model.final_action_clip_value", None))


def is_checkpoint(path: Path) -> bool:
    """A DPPO checkpoint: a `.pt` file, or a folder holding one or more."""
    return (path.is_file() and path.suffix == ".pt") or (path.is_dir() and any(path.glob("*.pt")))


def checkpoint_files(path: Path) -> tuple[Path, Path, Path]:
    """The checkpoint, the config and the normalization file of a DPPO checkpoint (a folder or a `.pt`
    in one); one-line UserError naming what is missing."""
    folder = path.parent if path.is_file() else path
    checkpoints = [path] if path.is_file() else sorted(path.glob("*.pt"))
    if len(checkpoints) > 1:
        names = ", ".join(p.name for p in checkpoints)
        raise UserError(f"{folder} holds {len(checkpoints)} checkpoints ({names}); name one, e.g. "
                        f"{checkpoints[-1]}")
    configs = sorted([*folder.glob("*.yaml"), *folder.glob("*.yml")])
    if len(configs) != 1:
        found = f"{len(configs)} (" + ", ".join(p.name for p in configs) + ")" if configs else "none"
        raise UserError(f"{folder}: a DPPO checkpoint needs its run's config beside it, one *.yaml, found "
                        f"{found}")
    normalization = folder / NORMALIZATION
    if not normalization.is_file():
        raise UserError(f"{folder}: no {NORMALIZATION} (DPPO's, from "
                        f"$DPPO_DATA_DIR/<suite>/<env>/{NORMALIZATION})")
    return checkpoints[0], configs[0], normalization


def checkpoint_networks(path: Path, cfg: DPPOConfig) -> tuple[DiffusionMLP, DiffusionMLP | None]:
    """The base network and, for a fine-tuned checkpoint run with ft_denoising_steps > 0, the fine-tuned
    one, from the state dict DPPO reads: "model" for DiffusionEval (DPPO's eval), else "ema" where
    present, else "model"; tensors under `actor.` where there are any, else `network.`; the fine-tuned
    ones under `actor_ft.`. One-line UserError for a tensor missing or of another shape."""
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch's unpickler raises several types for a file it cannot read
        raise UserError(f"{path}: torch.load(weights_only=True) cannot read it ({type(exc).__name__}); "
                        "DPPO's checkpoints hold only tensors and numbers") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: not a DPPO checkpoint (a dict holding 'model', and 'ema' when "
                        "pre-training)")
    entry = "ema" if cfg.sampler != "DiffusionEval" and "ema" in data else "model"
    state = data.get(entry)
    if not isinstance(state, dict):
        raise UserError(f"{path}: no {entry!r} state dict (DPPO saves 'model', and 'ema' when pre-training)")
    prefix = "actor." if any(k.startswith("actor.") for k in state) else "network."
    base = _network(state, prefix, cfg.network, path)
    if not (cfg.ft_below and any(k.startswith("actor_ft.") for k in state)):
        return base, None
    return base, _network(state, "actor_ft.", cfg.network, path)


def _network(state: dict, prefix: str, spec: NetworkSpec, path: Path) -> DiffusionMLP:
    tensors = {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
    if not tensors:
        raise UserError(f"{path}: no tensors under network. or actor. (DPPO's DiffusionMLP weights)")
    for key, value in sorted(tensors.items()):
        if not isinstance(value, torch.Tensor):
            raise UserError(f"{path}: {prefix}{key} is not a tensor")
    given = {key: tuple(value.shape) for key, value in tensors.items()}
    wanted = planned_shapes(lambda: DiffusionMLP(spec), str(path))
    if problem := mismatch(given, wanted, "the config's DiffusionMLP", prefix):
        raise UserError(f"{path}: {problem}")
    network = DiffusionMLP(spec)
    network.load_state_dict(tensors)
    return network.eval()


def read_normalization(path: Path, cfg: DPPOConfig) -> dict[str, np.ndarray]:
    """obs_min, obs_max [obs_dim] and action_min, action_max [action_dim] from DPPO's normalization.npz."""
    try:
        with np.load(path) as npz:
            arrays = {k: np.asarray(npz[k]) for k in npz.files}
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: not an .npz file ({str(exc).splitlines()[0]})") from None
    sizes = {"obs_min": cfg.obs_dim, "obs_max": cfg.obs_dim, "action_min": cfg.network.action_dim,
             "action_max": cfg.network.action_dim}
    for key, size in sizes.items():
        value = arrays.get(key)
        if value is None:
            raise UserError(f"{path}: no {key!r} (DPPO's normalization holds {', '.join(sizes)})")
        if value.shape != (size,) or value.dtype.kind != "f" or not np.isfinite(value).all():
            raise UserError(f"{path}: {key} must be {size} finite floats, got {value.dtype} "
                            f"{list(value.shape)}")
    return {key: arrays[key] for key in sizes}


class DPPOPolicy:
    """A DPPO diffusion MLP as a NoisePolicy. `act` takes DPPO's low-dim observations, unnormalised (the
    env's state vector, [B, obs_dim], or with cond_steps > 1 the last cond_steps of them [B, cond_steps,
    obs_dim]), and returns the first act_steps actions of the chunk, unnormalised for the env."""

    def __init__(self, cfg: DPPOConfig, base: DiffusionMLP, ft: DiffusionMLP | None,
                 normalization: dict[str, np.ndarray], name: str):
        self.cfg, self.name, self.normalization = cfg, name, normalization
        self.networks = {"base": base} | ({"ft": ft} if ft is not None else {})  # float32, as trained
        self._net64 = {k: copy.deepcopy(v).double() for k, v in self.networks.items()}
        n = normalization
        self._obs_min = torch.tensor(n["obs_min"], dtype=torch.float64)
        scale = n["obs_max"] - n["obs_min"] + 1e-6  # in the file's dtype, as DPPO's wrappers compute it
        self._obs_scale = torch.tensor(scale, dtype=torch.float64)
        self._action_min = torch.tensor(n["action_min"], dtype=torch.float64)
        self._action_range = torch.tensor(n["action_max"] - n["action_min"], dtype=torch.float64)
        ac = alphas_cumprod(cfg.denoising_steps).double()
        ratio = cfg.denoising_steps // cfg.ddim_steps
        times = [(cfg.ddim_steps - 1 - i) * ratio for i in range(cfg.ddim_steps)]
        alphas = [ac[t] for t in times]
        previous = [*alphas[1:], torch.tensor(1.0, dtype=torch.float64)]
        self._steps = list(zip(times, alphas, previous, strict=True))  # (t, alpha-bar_t, alpha-bar_prev)

    noise_shape = property(lambda self: (self.cfg.network.horizon_steps, self.cfg.network.action_dim))
    n_exec = property(lambda self: self.cfg.act_steps)
    n_obs_steps = property(lambda self: self.cfg.cond_steps)

    def act(self, obs: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """obs [B, obs_dim] or [B, cond_steps, obs_dim], noise [B, H, A] -> actions [B, act_steps, A]."""
        x = in_blocks(self._denoise, self._normalised(obs), noise)[:, : self.cfg.act_steps]
        return on_grid((x + 1) / 2 * self._action_range + self._action_min)

    def _normalised(self, obs) -> torch.Tensor:
        """Observations scaled to [-1, 1] as DPPO's env wrappers scale them, steps flattened oldest first."""
        n, d = self.cfg.cond_steps, self.cfg.obs_dim
        wanted = f"[B, {d}]" if n == 1 else f"[B, {n}, {d}]"
        if isinstance(obs, dict):
            raise UserError(f"policy {self.name!r} sees DPPO's low-dim state {wanted}, got observations with "
                            f"keys {sorted(obs)}")
        obs = float64(obs)
        if obs.ndim != (2 if n == 1 else 3) or tuple(obs.shape[1:]) != ((d,) if n == 1 else (n, d)):
            raise UserError(f"policy {self.name!r} sees DPPO's low-dim state {wanted}, got {list(obs.shape)}")
        return (2 * ((obs - self._obs_min) / self._obs_scale - 0.5)).reshape(len(obs), n * d)

    def _denoise(self, cond: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """DPPO's DDIM, eta = 0, from x_T = the noise: x0 clipped to denoised_clip_value (epsilon then
        recomputed from it), epsilon to eps_clip_value, the last step's sample to final_action_clip_value."""
        cfg = self.cfg
        for t, a, a_prev in self._steps:
            net = self._net64["ft" if t < cfg.ft_below and "ft" in self._net64 else "base"]
            eps = net(x, torch.full((len(x),), float(t), dtype=torch.float64), cond)
            x0 = (x - (1 - a).sqrt() * eps) / a.sqrt()
            if cfg.denoised_clip_value is not None:
                x0 = x0.clamp(-cfg.denoised_clip_value, cfg.denoised_clip_value)
                eps = (x - a.sqrt() * x0) / (1 - a).sqrt()
            if cfg.eps_clip_value is not None:
                eps = eps.clamp(-cfg.eps_clip_value, cfg.eps_clip_value)
            x = a_prev.sqrt() * x0 + (1 - a_prev).sqrt() * eps
        if cfg.final_action_clip_value is not None:
            x = x.clamp(-cfg.final_action_clip_value, cfg.final_action_clip_value)
        return x

    def fingerprint(self) -> str:
        """A hash of the weights, the normalization and the acting settings, and the DDIM step count."""
        digest = hashlib.sha256(json.dumps(asdict(self.cfg), sort_keys=True).encode())
        for role, network in sorted(self.networks.items()):
            for key, value in sorted(network.state_dict().items()):
                digest.update(f"{role}.{key}".encode() + value.contiguous().numpy().tobytes())
        for key, value in self.normalization.items():
            digest.update(key.encode() + np.ascontiguousarray(value).tobytes())
        return f"dppo-{digest.hexdigest()[:16]}@{self.cfg.ddim_steps}"


def load(path: str | Path, steps: int | None = None, name: str | None = None) -> DPPOPolicy:
    """The DPPO checkpoint at `path` (a folder or its `.pt`) as a policy, with `steps` DDIM steps (default:
    the config's ddim_steps, else its denoising_steps); one-line UserError for what it cannot run."""
    checkpoint, config, normalization = checkpoint_files(Path(path))
    cfg = read_config(config, steps)
    base, ft = checkpoint_networks(checkpoint, cfg)
    return DPPOPolicy(cfg, base, ft, read_normalization(normalization, cfg), name or str(path))


CONFIG = """\
_target_: agent.pretrain.train_diffusion_agent.TrainDiffusionAgent
obs_dim: {obs_dim}
action_dim: {s.action_dim}
denoising_steps: {denoising_steps}
horizon_steps: {s.horizon_steps}
cond_steps: {cond_steps}
act_steps: {act_steps}

model:
  _target_: model.diffusion.diffusion.DiffusionModel
  predict_epsilon: True
  denoised_clip_value: 1.0
  network:
    _target_: model.diffusion.mlp_diffusion.DiffusionMLP
    time_dim: {s.time_dim}
    mlp_dims: {mlp_dims}
    cond_mlp_dims: {cond_mlp_dims}
    activation_type: {s.activation_type}
    out_activation_type: {s.out_activation_type}
    use_layernorm: {s.use_layernorm}
    residual_style: {s.residual_style}
    cond_dim: ${{eval:'${{obs_dim}} * ${{cond_steps}}'}}
    horizon_steps: ${{horizon_steps}}
    action_dim: ${{action_dim}}
  horizon_steps: ${{horizon_steps}}
  obs_dim: ${{obs_dim}}
  action_dim: ${{action_dim}}
  denoising_steps: ${{denoising_steps}}
"""


def save_checkpoint(folder: Path, network: DiffusionMLP, normalization: dict[str, np.ndarray], *,
                    denoising_steps: int, cond_steps: int = 1, act_steps: int | None = None, epoch: int = 0,
                    ema: DiffusionMLP | None = None) -> Path:
    """A trained DiffusionMLP written as DPPO's pre-training writes it: `state_{epoch}.pt` ({"epoch",
    "model", "ema"}, tensors under `network.`; `ema` defaults to `network`), `config.yaml` shaped as
    DPPO's robomimic pre-training configs (DDPM over `denoising_steps`, denoised_clip_value 1), and
    `normalization.npz` (obs_min, obs_max, action_min, action_max). Returns the checkpoint's path."""
    spec = network.spec
    obs_dim = spec.cond_dim // cond_steps
    states = {role: {f"network.{k}": v.detach().clone() for k, v in net.state_dict().items()}
              for role, net in (("model", network), ("ema", ema or network))}
    buffer = io.BytesIO()
    torch.save({"epoch": epoch, **states}, buffer)
    checkpoint = write_atomic(folder / f"state_{epoch}.pt", buffer.getvalue())
    write_atomic(folder / "config.yaml", CONFIG.format(
        s=spec, obs_dim=obs_dim, denoising_steps=denoising_steps, cond_steps=cond_steps,
        act_steps=act_steps or spec.horizon_steps, mlp_dims=list(spec.mlp_dims),
        cond_mlp_dims="null" if spec.cond_mlp_dims is None else list(spec.cond_mlp_dims)))
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{k: normalization[k] for k in ("obs_min", "obs_max", "action_min",
                                                                  "action_max")})
    write_atomic(folder / NORMALIZATION, buffer.getvalue())
    return checkpoint

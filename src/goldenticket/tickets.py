"""A golden ticket: one constant (H, A) float32 noise array, saved as one .safetensors file."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save

from goldenticket.errors import OptionError, UserError
from goldenticket.files import write_atomic

_TENSOR = "noise"
_META_KEY = "goldenticket"
_MAX_VALUES = 2**24  # far more than any (horizon, action_dim): a header declaring more is not a ticket


def _checked_noise(noise: Any, where: str) -> np.ndarray:
    """Return noise as a C-contiguous float32 copy, or raise UserError naming `where`."""
    arr = np.array(noise, dtype=np.float32, order="C")
    if arr.ndim != 2:
        raise UserError(f"{where}: noise must be 2-D (horizon, action_dim), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise UserError(f"{where}: noise contains NaN or inf")
    return arr


def _jsonable(value: Any) -> Any:
    """json.dumps fallback for numpy scalars and arrays."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"ticket metadata value of type {type(value).__name__} is not JSON-able")


@dataclass(eq=False)  # numpy arrays have no boolean ==; compare .id instead
class Ticket:
    """Constant noise fed to a frozen policy in place of fresh Gaussian noise, plus metadata."""

    noise: np.ndarray
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.noise = _checked_noise(self.noise, "ticket")

    @property
    def id(self) -> str:
        """12 hex chars of sha256 over the policy fingerprint (metadata `policy_fingerprint`:
        weights hash and denoising steps), the shape and the float32 noise bytes, so that one id
        names one ticket for one policy."""
        noise = np.ascontiguousarray(self.noise, dtype=np.float32)
        digest = hashlib.sha256(self.metadata.get("policy_fingerprint", "").encode())
        digest.update(repr(tuple(noise.shape)).encode())
        digest.update(noise.tobytes())
        return digest.hexdigest()[:12]

    def check_fits(self, fingerprint: str, task: str | None, where: str) -> None:
        """UserError unless the ticket was found for this policy (its identity, `policies.identity`)
        and, when `task` is given, for that task (one of its `tasks` for a multi-task ticket); a
        ticket without that metadata (made by hand) fits anything."""
        meta, found_for = self.metadata, []
        if meta.get("policy_fingerprint", fingerprint) != fingerprint:
            found_for.append(f"policy {meta.get('policy')} ({meta['policy_fingerprint']})")
        if task is not None and task not in meta.get("tasks", [meta.get("task", task)]):
            found_for.append(f"task {meta['task']}")
        if found_for:
            on = "" if task is None else f" on {task}"
            raise OptionError(f"{where}: ticket {self.id} was found for {' and '.join(found_for)}, not "
                              f"this policy ({fingerprint}){on}; allow_transfer runs it anyway",
                              "allow_transfer")

    def search_seeds(self) -> range | None:
        """The search seeds it was found on (metadata `search_seeds`: [first, last]), if recorded."""
        span = self.metadata.get("search_seeds")
        return None if span is None else range(span[0], span[1] + 1)

    def save(self, path: str | Path) -> Path:
        """Write one .safetensors file: tensor "noise" plus metadata as JSON in the header."""
        meta = json.dumps(self.metadata, sort_keys=True, default=_jsonable)
        noise = _checked_noise(self.noise, str(path))
        return write_atomic(path, save({_TENSOR: noise}, metadata={_META_KEY: meta}))

    @classmethod
    def load(cls, path: str | Path, expected_shape: tuple[int, ...] | None = None) -> Ticket:
        """Read a ticket written by save(); every problem is a one-line UserError. The header's
        dtype and shape are checked before the tensor is read."""
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: ticket file not found")
        try:
            with safe_open(str(path), framework="numpy") as f:
                names = f.keys()
                if _TENSOR not in names:
                    raise UserError(f"{path}: no 'noise' tensor (found {sorted(names)})")
                header = f.get_slice(_TENSOR)
                dtype, shape = header.get_dtype(), tuple(header.get_shape())
                if dtype != "F32":
                    raise UserError(f"{path}: noise dtype must be float32 (F32), got {dtype}")
                if expected_shape is not None and shape != tuple(expected_shape):
                    raise UserError(f"{path}: noise shape {shape} does not match the policy's "
                                    f"expected shape {tuple(expected_shape)}")
                if math.prod(shape) > _MAX_VALUES:
                    raise UserError(f"{path}: noise shape {shape} holds more than the {_MAX_VALUES} values a "
                                    "ticket may have")
                noise = f.get_tensor(_TENSOR)
                metadata = f.metadata() or {}
        except SafetensorError as e:
            raise UserError(f"{path}: not a valid safetensors file ({e})") from None
        return cls(_checked_noise(noise, str(path)), _parse_metadata(metadata, path))


_STRINGS = ("policy", "policy_fingerprint", "task")  # metadata that must be a string when present


def _parse_metadata(header: dict[str, str], path: Path) -> dict:
    """The ticket's metadata from its header, with the types the code reading it relies on."""
    try:
        metadata = json.loads(header.get(_META_KEY, "{}"))
    except (json.JSONDecodeError, RecursionError) as e:
        reason = "nested too deeply" if isinstance(e, RecursionError) else e
        raise UserError(f"{path}: ticket metadata is not valid JSON ({reason})") from None
    if not isinstance(metadata, dict):
        raise UserError(f"{path}: ticket metadata must be a JSON object")
    for key in _STRINGS:
        if not isinstance(metadata.get(key, ""), str):
            raise UserError(f"{path}: metadata {key} must be a string, got {type(metadata[key]).__name__}")
    tasks = metadata.get("tasks")
    if tasks is not None:
        if not (isinstance(tasks, list) and tasks and all(isinstance(t, str) for t in tasks)):
            raise UserError(f"{path}: metadata tasks must be a list of task names, got {tasks!r:.60}")
        if "task" not in metadata:
            raise UserError(f"{path}: metadata has tasks but no task")
    steps = metadata.get("max_steps")
    if steps is not None and not (type(steps) is int and steps > 0):
        raise UserError(f"{path}: metadata max_steps must be an integer > 0, got {steps!r:.40}")
    if not isinstance(metadata.get("success"), str | None):
        raise UserError(f"{path}: metadata success must be an import string or null")
    span = metadata.get("search_seeds")
    if span is not None and not (isinstance(span, list) and len(span) == 2
                                 and all(type(s) is int and s >= 0 for s in span) and span[0] <= span[1]):
        raise UserError(f"{path}: metadata search_seeds must be [first, last] seeds, got {span!r:.60}")
    return metadata


def zero_ticket(shape: tuple[int, int]) -> Ticket:
    """The all-zeros ticket: the mean of the Gaussian prior, a natural baseline."""
    return Ticket(np.zeros(shape, dtype=np.float32), {"method": "zero"})

"""A golden ticket: one constant (H, A) float32 noise array and its typed record, saved as one
.safetensors file (the record as JSON in the header: JSON only at the file edge)."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save

from goldenticket.errors import OptionError, UserError
from goldenticket.files import write_atomic

_TENSOR = "noise"
_META_KEY = "goldenticket"
MAX_VALUES = 2**24  # far more than any (horizon, action_dim): a header declaring more is not a ticket
ZERO_SOURCE = "zero ticket"  # the record's source when it is the zero ticket (w = 0)
GIVEN = "given: "  # the record's source of a ticket given to the job: "given: <file or id>"


def ticket_id(noise: np.ndarray, fingerprint: str | None) -> str:
    """12 hex chars of sha256 over the policy fingerprint (`policies.identity`: weights hash and
    denoising steps), the shape and the float32 noise bytes: one id names one ticket for one policy."""
    noise = np.ascontiguousarray(noise, dtype=np.float32)
    digest = hashlib.sha256((fingerprint or "").encode())
    digest.update(repr(tuple(noise.shape)).encode())
    digest.update(noise.tobytes())
    return digest.hexdigest()[:12]


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


@dataclass(frozen=True)
class TicketRecord:
    """What a ticket is for, how it came, and how it was judged. Identity: the policy (`policy`, its
    `policy_fingerprint`), `noise_shape`, the `task` (`tasks` for a multi-task ticket) and the
    episode settings (`max_steps`, `success`). Provenance: `source` (None for a search's ticket,
    ZERO_SOURCE, or GIVEN + its file or id) and the search's settings. Results: its scores on the
    search and validation seeds and its held-out row (`heldout`, as summary.json writes it).
    `extra` keeps keys this version does not know, so a file reads back as it was written."""

    policy: str | None = None
    policy_fingerprint: str | None = None
    noise_shape: tuple[int, int] | None = None
    task: str | None = None
    tasks: tuple[str, ...] | None = None
    max_steps: int | None = None
    success: str | None = None
    source: str | None = None
    method: str | None = None
    subspace: str | None = None
    searched_shape: tuple[int, ...] | None = None
    budget: int | None = None
    episodes_used: int | None = None
    seed: int | None = None
    objective: str | None = None
    search_seeds: tuple[int, int] | None = None
    search_score: float | None = None
    search_episodes: int | None = None
    validation_score: float | None = None
    validation_seeds: tuple[int, int] | None = None
    heldout: dict | None = None
    front: dict | None = None
    extra: dict = field(default_factory=dict)

    @property
    def provenance(self) -> str:
        """"search", "zero" or "given" ("unknown" for a ticket made by hand)."""
        if self.source == ZERO_SOURCE or (self.source is None and self.method == "zero"):
            return "zero"
        if self.source is not None:
            return "given"
        return "search" if self.method is not None else "unknown"

    def to_metadata(self) -> dict:
        """The record as the file's JSON: unset fields left out, except `success` for a ticket that
        names its task (null: the task's own signal) and `search_score` for one whose source is
        known (null: not searched)."""
        meta = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        meta = {k: list(v) if isinstance(v, tuple) else v for k, v in meta.items() if v is not None}
        if self.task is not None:
            meta["success"] = self.success
        if self.source is not None:
            meta["search_score"] = self.search_score
        return meta | self.extra

    @classmethod
    def from_metadata(cls, meta: dict, where: str, shape: tuple[int, ...] | None = None) -> TicketRecord:
        """The record of a file's JSON `meta`, each known key checked; UserError naming `where`."""
        if not isinstance(meta, dict):
            raise UserError(f"{where}: ticket metadata must be a JSON object")
        known = {f.name for f in fields(cls)} - {"extra"}
        for key, check in _CHECKS.items():
            if meta.get(key) is not None and (reason := check(meta[key])):
                raise UserError(f"{where}: metadata {key} {reason}, got {meta[key]!r:.60}")
        if meta.get("tasks") is not None and "task" not in meta:
            raise UserError(f"{where}: metadata has tasks but no task")
        if shape is not None and meta.get("noise_shape") is not None and tuple(meta["noise_shape"]) != shape:
            raise UserError(f"{where}: metadata noise_shape {meta['noise_shape']} contradicts the noise "
                            f"tensor's shape {list(shape)}")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in meta.items() if k in known}
        return cls(**values, extra={k: v for k, v in meta.items() if k not in known})


def _string(value) -> str | None:
    if not isinstance(value, str):
        return f"must be a string, got {type(value).__name__}"
    return None if value.isprintable() else "must be printable text (no control characters)"


def _count(value) -> str | None:
    return None if type(value) is int and value >= 0 else "must be an integer >= 0"


def _score(value) -> str | None:
    return None if type(value) in (int, float) else "must be a number"


def _span(value) -> str | None:
    good = isinstance(value, list) and len(value) == 2 and all(type(s) is int and s >= 0 for s in value)
    return None if good and value[0] <= value[1] else "must be [first, last] seeds"


def _shape(value) -> str | None:
    good = isinstance(value, list) and len(value) == 2 and all(type(n) is int and n > 0 for n in value)
    return None if good else "must be [horizon, action_dim], two integers > 0"


def _tasks(value) -> str | None:
    if not (isinstance(value, list) and value and all(isinstance(t, str) for t in value)):
        return "must be a list of task names"
    return None if all(t.isprintable() for t in value) else "must be printable text (no control characters)"


def _steps(value) -> str | None:
    return None if type(value) is int and value > 0 else "must be an integer > 0"


_CHECKS = {
    "policy": _string, "policy_fingerprint": _string, "task": _string, "source": _string, "method": _string,
    "subspace": _string, "objective": _string, "tasks": _tasks, "max_steps": _steps,
    "success": lambda v: _string(v) and "must be an import string or null", "noise_shape": _shape,
    "searched_shape": lambda v: None if isinstance(v, list) and all(type(n) is int for n in v) else
    "must be a list of integers", "budget": _count, "episodes_used": _count, "seed": _count,
    "search_episodes": _count, "search_seeds": _span, "validation_seeds": _span, "search_score": _score,
    "validation_score": _score, "heldout": lambda v: None if isinstance(v, dict) else "must be an object",
    "front": lambda v: None if isinstance(v, dict) else "must be an object",
}


@dataclass(frozen=True, eq=False)  # numpy arrays have no boolean ==; compare .id instead
class Ticket:
    """Constant noise fed to a frozen policy in place of fresh Gaussian noise, and its record."""

    noise: np.ndarray
    record: TicketRecord = TicketRecord()

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise", _checked_noise(self.noise, "ticket"))

    @property
    def id(self) -> str:
        """`ticket_id` of the noise for the policy the record names."""
        return ticket_id(self.noise, self.record.policy_fingerprint)

    @property
    def metadata(self) -> dict:
        """The record as the file's JSON (`TicketRecord.to_metadata`)."""
        return self.record.to_metadata()

    def with_record(self, **changes) -> Ticket:
        """The same noise with its record's fields changed."""
        return Ticket(self.noise, replace(self.record, **changes))

    def check_fits(self, fingerprint: str, task: str | None, where: str) -> None:
        """UserError unless the ticket was found for this policy (its identity, `policies.identity`)
        and, when `task` is given, for that task (one of its `tasks` for a multi-task ticket); a
        ticket without that record (made by hand) fits anything."""
        record, found_for = self.record, []
        if record.policy_fingerprint not in (None, fingerprint):
            found_for.append(f"policy {record.policy} ({record.policy_fingerprint})")
        if task is not None and task not in (record.tasks or (record.task or task,)):
            found_for.append(f"task {record.task}")
        if found_for:
            on = "" if task is None else f" on {task}"
            raise OptionError(f"{where}: ticket {self.id} was found for {' and '.join(found_for)}, not "
                              f"this policy ({fingerprint}){on}; allow_transfer runs it anyway",
                              "allow_transfer")

    def search_seeds(self) -> range | None:
        """The search seeds it was found on, if recorded."""
        span = self.record.search_seeds
        return None if span is None else range(span[0], span[1] + 1)

    def save(self, path: str | Path) -> Path:
        """Write one .safetensors file: tensor "noise" plus the record as JSON in the header."""
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
                if math.prod(shape) > MAX_VALUES:
                    raise UserError(f"{path}: noise shape {shape} holds more than the {MAX_VALUES} values a "
                                    "ticket may have")
                noise = f.get_tensor(_TENSOR)
                header_meta = f.metadata() or {}
        except SafetensorError as e:
            raise UserError(f"{path}: not a valid safetensors file ({e})") from None
        return cls(_checked_noise(noise, str(path)), _record(header_meta, path, shape))


def _record(header: dict[str, str], path: Path, shape: tuple[int, ...]) -> TicketRecord:
    """The ticket's record from its header."""
    try:
        metadata = json.loads(header.get(_META_KEY, "{}"))
    except (json.JSONDecodeError, RecursionError) as e:
        reason = "nested too deeply" if isinstance(e, RecursionError) else e
        raise UserError(f"{path}: ticket metadata is not valid JSON ({reason})") from None
    return TicketRecord.from_metadata(metadata, str(path), shape)


def zero_ticket(shape: tuple[int, int]) -> Ticket:
    """The all-zeros ticket: the mean of the Gaussian prior, a natural baseline."""
    return Ticket(np.zeros(shape, dtype=np.float32), TicketRecord(method="zero"))

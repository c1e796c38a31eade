"""What a policy folder holds, checked before anything is built from it: its JSON files read in one
line, the size of the network its config describes, and its tensors' names and shapes against
that network's."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn

from goldenticket.errors import UserError

MAX_PARAMETERS = 2**26  # numbers a folder's network may hold: 256 MiB in float32, far past any policy here


def read_json(path: Path):
    """The JSON value in `path`; a one-line UserError for a file that cannot be read or is not JSON."""
    try:
        return json.loads(path.read_text())
    except OSError as exc:
        raise UserError(f"cannot read {path}: {exc.strerror}") from None
    except RecursionError:
        raise UserError(f"{path}: not a JSON file (nested too deeply)") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, an integer of too many digits
        raise UserError(f"{path}: not a JSON file ({str(exc).splitlines()[0]})") from None


def shown(value) -> str:
    """A value as a one-line message shows it: its repr, cut at 80 characters."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def planned_shapes(build: Callable[[], nn.Module], where: str) -> dict[str, tuple[int, ...]]:
    """The state dict's shapes of the network `build()` makes, built on the meta device (no memory
    used); a one-line UserError naming `where` for a network of more than MAX_PARAMETERS numbers."""
    with torch.device("meta"):
        shapes = {key: tuple(value.shape) for key, value in build().state_dict().items()}
    size = sum(math.prod(shape) for shape in shapes.values())
    if size > MAX_PARAMETERS:
        raise UserError(f"{where}: the network it describes holds {size:,} numbers, more than the "
                        f"{MAX_PARAMETERS:,} a policy folder may hold")
    return shapes


def mismatch(given: dict[str, tuple[int, ...]], wanted: dict[str, tuple[int, ...]], network: str,
             prefix: str = "") -> str | None:
    """What keeps tensors of the `given` shapes from loading into `network`, whose state dict has the
    `wanted` ones (the first tensor of no place or of another shape, else the first missing); None
    when they fit. `prefix` is how the file names the network's tensors."""
    for key, shape in sorted(given.items()):
        if key not in wanted:
            return f"tensor {prefix}{key} {list(shape)} has no place in {network}"
        if shape != wanted[key]:
            return f"tensor {prefix}{key} has shape {list(shape)}; {network} needs {list(wanted[key])}"
    missing = sorted(wanted.keys() - given.keys())
    if not missing:
        return None
    more = f" ({len(missing) - 1} more missing)" if len(missing) > 1 else ""
    return f"no tensor {prefix}{missing[0]} {list(wanted[missing[0]])}, which {network} needs{more}"

"""A typed option: a dataclass field with its default, its help, whether it changes a run's results and
how the command line spells it; and the check that a given value is of its field's annotated type.
Config's options and each search method's settings are made of them."""

from __future__ import annotations

import functools
import typing
from collections.abc import Sequence
from dataclasses import MISSING, field, fields
from types import UnionType

from goldenticket.errors import OptionError


def option(default=MISSING, help: str = "", changes_results: bool = True, **cli) -> field:
    """A config field (one without a default must be given); `changes_results=False` for one a rerun
    may change (where episodes run, a limit, logging: a run's store does not hold it); `cli` holds how
    the command line spells it beyond the generated flag (choices, action, its own flag)."""
    return field(default=default, metadata={"help": help, "changes_results": changes_results, "cli": cli})


def changes_results(f) -> bool:
    """Whether field `f` (an `option`) can change a run's results, so that another value is another run."""
    return f.metadata["changes_results"]


@functools.cache
def field_types(cls) -> dict:
    """Each field's annotation of `cls`, evaluated (the modules postpone them: `f.type` is a string)."""
    return typing.get_type_hints(cls)


def check_types(cls, values: dict) -> None:
    """OptionError naming the first value that is not of its field's annotated type."""
    for f in fields(cls):
        if f.name in values and not conforms(value := values[f.name], field_types(cls)[f.name]):
            raise OptionError(f"{f.name} must be of type {f.type}, got {value!r} ({type(value).__name__})",
                              f.name)


def conforms(value, hint) -> bool:
    """Whether `value` is of type `hint`: a bool is no int, an int is a float, a list is a tuple, and a
    range is a Sequence[int]."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (UnionType, typing.Union):
        return any(conforms(value, arg) for arg in args)
    if origin in (tuple, Sequence):
        if isinstance(value, range):
            return origin is Sequence and args[0] is int
        return isinstance(value, tuple | list) and all(conforms(v, args[0]) for v in value)
    if hint in (int, float):
        return isinstance(value, int | hint) and not isinstance(value, bool)
    return isinstance(value, hint)

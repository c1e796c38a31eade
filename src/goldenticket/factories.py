"""Objects named by import strings, `package.module:factory` (as uvicorn and entry points name
them), so that worker processes can rebuild a user's policy or environment by name."""

from __future__ import annotations

import functools
import importlib
import os
import sys
from pathlib import Path

from goldenticket.errors import UserError


def is_import_string(name: str) -> bool:
    """`pkg.mod:factory` (and not an existing path, which may contain a colon)."""
    module, colon, attr = name.partition(":")
    return bool(colon and module and attr) and not Path(name).exists()


def build(name: str, what: str):
    """Import `package.module` (the current folder is on the path, as for `python -m`) and call
    its `factory` with no arguments; every failure is a one-line UserError naming `what`."""
    module_name, _, attr = name.partition(":")
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise UserError(f"{what} {name!r}: cannot import {module_name} ({exc})") from None
    try:
        factory = functools.reduce(getattr, attr.split("."), module)
    except AttributeError:
        raise UserError(f"{what} {name!r}: {module_name} has no {attr}") from None
    if not callable(factory):
        raise UserError(f"{what} {name!r}: {attr} is not callable")
    try:
        return factory()
    except Exception as exc:  # the user's code: report it in one line
        raise UserError(f"{what} {name!r}: {attr}() failed: {type(exc).__name__}: {exc}") from None

"""Objects named by import strings, `package.module:factory` (as uvicorn and entry points name
them), so that worker processes can rebuild a user's policy or environment by name."""

from __future__ import annotations

import functools
import importlib
import multiprocessing as mp
import os
import pickle
import subprocess
import sys
import sysconfig
import traceback
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import spawn
from pathlib import Path

from goldenticket.errors import UserError

# Where code that is not the user's lives: goldenticket, the standard library, installed packages.
_NOT_USERS = ("<frozen", *{os.path.join(path, "") for path in (
    str(Path(__file__).parent), *map(sysconfig.get_path, ("stdlib", "purelib", "platlib")))})


def is_import_string(name: str) -> bool:
    """`pkg.mod:factory` (and not an existing path, which may contain a colon)."""
    module, colon, attr = name.partition(":")
    return bool(colon and module and attr) and not Path(name).exists()


def resolve(name: str, what: str):
    """The callable `factory` of `package.module` (the current folder is on the path, as for
    `python -m`); every failure is a one-line UserError naming `what`."""
    module_name, _, attr = name.partition(":")
    if module_name.startswith("."):  # importlib needs a package to resolve it against
        raise UserError(f"{what} {name!r}: import string {name} is relative; name the module by its full "
                        "path, package.module:factory")
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())
    try:
        module = call_users(importlib.import_module, f"{what} {name!r}: importing {module_name}", module_name)
    except UserError as exc:
        if isinstance(exc.__cause__, ImportError):
            raise UserError(f"{what} {name!r}: cannot import {module_name} ({exc.__cause__})") from None
        raise
    try:
        factory = functools.reduce(getattr, attr.split("."), module)
    except AttributeError:
        raise UserError(f"{what} {name!r}: {module_name} has no {attr}") from None
    if not callable(factory):
        raise UserError(f"{what} {name!r}: {attr} is not callable")
    return factory


def build(factory, what: str):
    """Call `factory` (a callable or an import string naming one) with no arguments; its failure
    is a one-line UserError naming `what`."""
    label = factory if isinstance(factory, str) else import_name(factory)
    if isinstance(factory, str):
        factory = resolve(factory, what)
    return call_users(factory, f"{what} {label!r}: {label.rpartition(':')[2]}()")


def call_users(fn, what: str, *args):
    """`fn(*args)`, a function of the user's; any exception from it (a UserError passes as it is)
    becomes the one-line `user_failure(what, exc)`, with the exception as its cause."""
    try:
        return fn(*args)
    except UserError:
        raise
    except Exception as exc:  # the user's code: report it in one line
        raise user_failure(what, exc) from exc


def user_failure(what: str, exc: BaseException) -> UserError:
    """`<what> failed at <file>:<line>: <exception>` in one line: the line is the deepest frame of
    the traceback in the user's own code (not goldenticket's, the standard library's or an installed
    package's), left out if there is none."""
    frames = traceback.extract_tb(exc.__traceback__)
    frame = next((f for f in reversed(frames) if not f.filename.startswith(_NOT_USERS)), None)
    where = f" at {frame.filename}:{frame.lineno}" if frame else ""
    message = " ".join(str(exc).split())  # one line, whatever the exception's text
    return UserError(f"{what} failed{where}: {type(exc).__name__}" + (f": {message}" if message else ""))


def import_name(obj) -> str:
    """`module:qualname` of a function or class (an instance: of its class), the name the CLI
    would import it by; a script's `__main__` is named by the script's file (`mine.py`: `mine`)."""
    target = obj if hasattr(obj, "__qualname__") else type(obj)
    module = target.__module__
    if module in ("__main__", "__mp_main__") and getattr(sys.modules[module], "__file__", None):
        module = Path(sys.modules[module].__file__).stem
    return f"{module}:{target.__qualname__}"


def picklable(obj, what: str) -> bytes:
    """`obj` pickled (by reference to an importable module, as multiprocessing does); UserError if it
    cannot be sent to a worker process."""
    try:
        return pickle.dumps(obj)
    except Exception as exc:  # pickle raises several types for a lambda, a local or a lock
        raise UserError(f"{what} cannot be sent to a worker process ({type(exc).__name__}: {exc}); "
                        "define it at module level, or name it by an import string") from None


def spawnable(what: str) -> None:
    """UserError if a spawned process cannot start here: it re-runs the main script, which must be a file
    (not one read from standard input, `python - < script.py`)."""
    main = spawn.get_preparation_data(what).get("init_main_from_path")
    if main is not None and not os.path.isfile(main):
        raise UserError(f"{what} cannot start: a spawned process re-runs the main script, {main}, which is "
                        "not a file (a script read from standard input?); save the script to a file and run "
                        "that")


def in_another_process(fn, *args, what: str):
    """`fn(*args)` in a fresh process, the way worker processes rebuild the user's objects: a new
    interpreter when nothing sent comes from the main script (a script read from standard input, or
    one with no `__main__` guard, may call it then), else a spawned process, which re-runs it."""
    sent = picklable((fn, args), what)
    if b"__main__" not in sent:
        return _in_new_interpreter(sent, what)
    spawnable(f"{what}: another process")
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        try:
            return pool.submit(fn, *args).result()
        except BrokenProcessPool:
            raise UserError(f"{what}: another process could not rebuild it; is its module importable "
                            "there, and does a script that calls goldenticket guard its entry point "
                            "with `if __name__ == '__main__':`?") from None


_RUN_SENT = """
import os, pickle, sys
answer = os.fdopen(os.dup(1), "wb")
os.dup2(2, 1)  # what the call prints goes to stderr; stdout carries the answer
sys.path[:] = pickle.loads(bytes.fromhex(sys.stdin.buffer.readline().decode()))
fn, args = pickle.loads(sys.stdin.buffer.read())
try:
    out = (True, fn(*args))
except Exception as exc:
    out = (False, exc)
answer.write(pickle.dumps(out))
"""


def _in_new_interpreter(sent: bytes, what: str):
    """Unpickle `sent` = (fn, args) in a new Python interpreter on this one's path, and return what
    `fn(*args)` returns there (or raise what it raised)."""
    stdin = pickle.dumps(sys.path).hex().encode() + b"\n" + sent
    done = subprocess.run([sys.executable, "-c", _RUN_SENT], input=stdin, capture_output=True, check=False)
    try:
        ok, value = pickle.loads(done.stdout)
    except Exception:  # it died, or printed no answer
        last = (done.stderr.decode(errors="replace").strip().splitlines() or ["no message"])[-1]
        raise UserError(f"{what}: another process could not rebuild it ({last})") from None
    if not ok:
        raise value
    return value

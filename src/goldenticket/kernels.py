"""OpenBLAS's kernels, which robosuite's controller depends on.

robosuite's controller runs numpy's linear algebra, and numpy's OpenBLAS picks its kernels per CPU
when numpy loads, so a robomimic episode differs in its last bits between CPUs (and rollouts are
chaotic). The recorded robomimic numbers come from OpenBLAS's Haswell kernels, which every x86-64
CPU with AVX2 and FMA runs: `pin` chooses them for a process that will run robomimic's tasks,
before numpy loads; `note` says once where a process runs others anyway.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
from collections.abc import Iterable
from pathlib import Path

VARIABLE, REFERENCE = "OPENBLAS_CORETYPE", "Haswell"
# the cores whose kernels gave the recorded robomimic numbers (the same episodes)
REFERENCE_KERNELS = (REFERENCE, "Zen")
ROBOMIMIC = "robomimic/"  # the prefix of robomimic's task and bundled policy names


def pin(names: Iterable[object]) -> bool:
    """Have OpenBLAS load Haswell's kernels if any of `names` (tasks, policies) is robomimic's, numpy
    has not loaded yet, the user chose no kernels and the CPU runs them; whether it did. Child
    processes inherit the choice."""
    if "numpy" in sys.modules or not _wants_haswell_kernels(names):
        return False
    os.environ[VARIABLE] = REFERENCE
    return True


def restart_pinned(names: Iterable[object]) -> None:
    """`pin` for a script that has loaded numpy already (a benchmark): where `pin` would choose
    Haswell's kernels, run the script again from the start with them. Call it before any work."""
    if _wants_haswell_kernels(names):
        os.environ[VARIABLE] = REFERENCE
        os.execv(sys.executable, sys.orig_argv)


def _wants_haswell_kernels(names: Iterable[object]) -> bool:
    """Whether any of `names` is robomimic's, the user chose no kernels and the CPU runs Haswell's."""
    wanted = any(isinstance(name, str) and name.startswith(ROBOMIMIC) for name in names)
    return wanted and VARIABLE not in os.environ and _runs_haswell_kernels()


def _runs_haswell_kernels() -> bool:
    """Whether this CPU has AVX2 and FMA, which Haswell's kernels use (Linux's /proc/cpuinfo)."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    flags = next((line.split(":", 1)[1] for line in info.splitlines() if line.startswith("flags")), "")
    return {"avx2", "fma"} <= set(flags.split())


@functools.cache
def note() -> None:
    """Say once when numpy's OpenBLAS runs other kernels than the recorded robomimic numbers did."""
    core = openblas_kernels()
    if core is not None and core not in REFERENCE_KERNELS:
        print(f"goldenticket: note: numpy's OpenBLAS runs its {core} kernels here, so robosuite's controller "
              "differs in the last bits from the recorded robomimic numbers (made with its Haswell kernels); "
              f"to reproduce them exactly, start Python with {VARIABLE}={REFERENCE} (any CPU with AVX2), as "
              "the goldenticket command does by itself", file=sys.stderr)


def openblas_kernels() -> str | None:
    """The core whose kernels numpy's OpenBLAS runs, asked of the loaded library (Linux); None where
    it cannot be found."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return None
    libraries = sorted({line.split()[-1] for line in maps.splitlines() if "openblas" in line.lower()})
    for library in libraries:
        for symbol in ("openblas_get_corename64_", "scipy_openblas_get_corename64_", "openblas_get_corename"):
            function = getattr(ctypes.CDLL(library), symbol, None)
            if function is not None:
                function.restype = ctypes.c_char_p
                return function().decode()
    return None

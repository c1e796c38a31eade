"""robomimic's episodes under the math-kernel settings one machine can force (as test_numerics.py does
for Meta-World's), with OpenBLAS's kernels fixed to Haswell's: robosuite's controller runs numpy's
linear algebra, whose kernels the recorded robomimic numbers depend on. Runs in robosuite's venv."""

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from test_numerics import RECORDER
from test_robomimic import robosuite_version

pytestmark = [pytest.mark.robomimic, pytest.mark.slow, pytest.mark.skipif(
    robosuite_version() != "1.5.2", reason="robosuite 1.5.2 is not installed (its own venv: README)")]

EPISODES = RECORDER + """
policy = Recorded(load_policy("robomimic/lift/ddim"))
seeds = seeds_in("heldout", 4)
ticket = Constant(np.full(policy.noise_shape, 0.3, np.float32))
results = rollout(policy, get_task("robomimic/lift"), [Episode(Gaussian(0), s) for s in seeds]
                  + [Episode(ticket, s) for s in seeds])
print(json.dumps({"episodes": [[r.success, r.length] for r in results],
                  "trajectories": policy.digest.hexdigest()}))
"""

# recorded on an AMD EPYC (AVX2, no AVX-512) with OpenBLAS's Haswell kernels: any CPU with AVX2 must
# reproduce it under OPENBLAS_CORETYPE=Haswell
RECORDED = "f15fac048b3e3754ffe33a8fb4d8d7bc53abd1c5bbc11a3a63ee12c50ef9e136"
KERNEL_VARIABLES = {"OPENBLAS_CORETYPE", "ATEN_CPU_CAPABILITY", "MKL_CBWR", "NPY_DISABLE_CPU_FEATURES"}


def _run(extra_env: dict[str, str], code: str = EPISODES) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in KERNEL_VARIABLES}
    return subprocess.run([sys.executable, "-c", code], env=env | extra_env, capture_output=True, text=True,
                          timeout=600)


def test_episodes_are_the_recorded_ones_under_every_kernel_setting():
    umath = np.core._multiarray_umath  # numpy < 2, robosuite's pin
    simd = " ".join(f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f))
    haswell = {"OPENBLAS_CORETYPE": "Haswell"}
    settings = [haswell, haswell | {"ATEN_CPU_CAPABILITY": "default"}, haswell | {"MKL_CBWR": "COMPATIBLE"}]
    if simd:
        settings.append(haswell | {"NPY_DISABLE_CPU_FEATURES": simd})
    with ThreadPoolExecutor(2) as pool:
        runs = list(pool.map(_run, settings))
    assert all(run.returncode == 0 for run in runs), [run.stderr for run in runs]
    results = [json.loads(run.stdout) for run in runs]
    outcomes = np.array(results[0]["episodes"])
    assert 0 < outcomes[:, 0].sum() < len(outcomes)  # borderline: some succeed, some fail
    assert all(r == results[0] for r in results) and results[0]["trajectories"] == RECORDED


def test_other_openblas_kernels_are_noted_once():
    code = ("import numpy\nfrom goldenticket.kernels import note as note_kernels\n"
            "note_kernels(); note_kernels()")
    other = _run({"OPENBLAS_CORETYPE": "Sandybridge"}, code)
    assert other.returncode == 0 and other.stderr.count("OPENBLAS_CORETYPE=Haswell") == 1
    assert "Sandybridge kernels" in other.stderr
    assert _run({"OPENBLAS_CORETYPE": "Haswell"}, code).stderr == ""


def test_the_command_runs_the_recorded_numbers_kernels_by_itself():
    code = ("import sys\nfrom goldenticket.cli import main\n"
            "rc = main(['evaluate', '--policy', 'robomimic/lift/ddim', '--task', 'robomimic/lift', "
            "'--seeds', '1000000:1000001', '--json'])\n"
            "from goldenticket.kernels import openblas_kernels\n"
            "print(rc, openblas_kernels(), file=sys.stderr)")
    run = _run({}, code)
    assert run.stderr.splitlines()[-1] == "0 Haswell", run.stderr
    assert "note:" not in run.stderr  # no advice to set a variable: the command chose the kernels
    chosen = _run({"OPENBLAS_CORETYPE": "Sandybridge"}, code)  # a user's own choice stands
    assert chosen.stderr.splitlines()[-1] == "0 Sandybridge" and "OPENBLAS_CORETYPE=Haswell" in chosen.stderr


def test_a_benchmark_that_loaded_numpy_restarts_with_the_recorded_numbers_kernels():
    code = ("import sys, numpy\nfrom goldenticket import kernels\n"
            "print('started', file=sys.stderr)\nkernels.restart_pinned({names})\n"
            "print(kernels.openblas_kernels(), file=sys.stderr)")
    run = _run({}, code.format(names="['robomimic/can']"))
    assert run.returncode == 0 and run.stderr.split() == ["started", "started", "Haswell"], run.stderr
    assert _run({}, code.format(names="['metaworld/reach-v3']")).stderr.count("started") == 1  # no restart
    chosen = _run({"OPENBLAS_CORETYPE": "Sandybridge"}, code.format(names="['robomimic/can']"))
    assert chosen.stderr.split() == ["started", "Sandybridge"]

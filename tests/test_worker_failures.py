"""Worker processes that die or cannot start end the run in one line, keeping what came back; a run
that works gives the same episodes in workers as in one process. The failing runs go in their own
process, so that a run that never ends fails its test instead of hanging it."""

import multiprocessing as mp
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from byo_example import BiasedController

from goldenticket.errors import UserError
from goldenticket.evaluation import Evaluator
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import Engine, Episode
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in

HERE = Path(__file__).parent
TASK = "byo_example:make_env"


class DiesOnTheZeroTicket(BiasedController):
    """Its process exits a moment after it is asked to act on the zero ticket."""

    def act(self, obs, noise):
        if not noise.any():
            time.sleep(1)  # the other worker's shards of the base come back first
            os._exit(1)
        return super().act(obs, noise)


def make_dying_policy():
    return DiesOnTheZeroTicket()


def make_policy_only_here():
    """A policy that cannot be built in a worker process (as one needing a device only this process has)."""
    if mp.current_process().name != "MainProcess":
        raise RuntimeError("no device in this process")
    return BiasedController()


def evaluate_until_a_worker_dies(store: str) -> None:
    """16 base episodes, then 16 on the zero ticket on which the workers die, in one engine call."""
    seeds, zero = seeds_in("heldout", 32), Constant(np.zeros((4, 2), np.float32))
    with Engine("test_worker_failures:make_dying_policy", get_task(TASK, max_steps=5), workers=2,
                shard_size=4) as engine:
        Evaluator(engine, RunStore(store)).run([("base", Gaussian(), seeds[:16]), ("zero", zero, seeds[16:])])


def evaluate_in_workers_that_cannot_start() -> None:
    task = get_task(TASK, max_steps=5)
    with Engine("test_worker_failures:make_policy_only_here", task, workers=2) as engine:
        engine.evaluate([Episode(Gaussian(), seed) for seed in seeds_in("heldout", 4)])


def _own_process(args: list[str], timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """`args` run in a process group of its own, killed with its workers if it outlives `timeout`."""
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    return subprocess.CompletedProcess(args, proc.returncode, stdout, stderr)


def _driven(call: str, module: str = "test_worker_failures", **kwargs) -> subprocess.CompletedProcess:
    """`call` of the test `module` in a process of its own (`kwargs`: Popen's, e.g. env); a UserError
    is its one line and exit code 2."""
    code = (f"import sys, {module} as t\n"
            "from goldenticket.errors import UserError\n"
            "try:\n"
            f"    t.{call}\n"
            "except UserError as exc:\n"
            "    print(exc, file=sys.stderr)\n"
            "    sys.exit(2)\n")
    return _own_process([sys.executable, "-c", code], timeout=120, cwd=HERE, **kwargs)


@pytest.mark.slow
def test_a_worker_that_dies_ends_the_run_in_one_line_keeping_the_shards_before(tmp_path):
    store = tmp_path / "run.sqlite"
    proc = _driven(f"evaluate_until_a_worker_dies({str(store)!r})")
    died = ("worker process died (exit code 1) while running episodes of "
            f"'test_worker_failures:make_dying_policy' on {TASK!r}\n")
    assert proc.returncode == 2 and proc.stderr == died, proc.stderr
    with sqlite3.connect(store) as con:
        assert con.execute("SELECT ticket_id, count(*) FROM episodes GROUP BY ticket_id").fetchall() == [
            ("base", 16)]


def test_a_worker_whose_main_process_has_gone_ends_quietly(capfd):
    """Its answers have nowhere to go (the main process was killed): no traceback, it just ends."""
    import pickle

    from goldenticket.local_pool import _serve

    main_end, worker_end = mp.Pipe()
    main_end.send((abs, -1))  # a shard was sent, then the main process went
    main_end.close()
    _serve(worker_end, pickle.dumps((int, ())))
    assert capfd.readouterr() == ("", "")


@pytest.mark.slow
def test_a_worker_that_cannot_build_the_policy_ends_the_run_in_one_line():
    proc = _driven("evaluate_in_workers_that_cannot_start()")
    assert proc.returncode == 2 and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith("a worker process could not start: policy 'test_worker_failures:"
                                  "make_policy_only_here': make_policy_only_here() failed at "
                                  f"{HERE / 'test_worker_failures.py'}:")
    assert proc.stderr.endswith(": RuntimeError: no device in this process\n")


def _from_standard_input(tmp_path, policy: str, task: str, workers: int) -> subprocess.CompletedProcess:
    script = tmp_path / "script.py"
    argv = ["evaluate", "--policy", policy, "--task", task, "--seeds", "1000000:1000004", "--max-steps", "10",
            "--workers", str(workers)]
    script.write_text(f"import sys\nfrom goldenticket.cli import main\n\nif __name__ == '__main__':\n"
                      f"    sys.exit(main({argv!r}))\n")
    with script.open() as stdin:
        return _own_process([sys.executable, "-"], timeout=120, stdin=stdin, cwd=HERE)


@pytest.mark.slow
def test_a_script_read_from_standard_input_stops_at_once_in_one_line_before_workers(tmp_path):
    proc = _from_standard_input(tmp_path, "metaworld/reach-v3/flow", "metaworld/reach-v3", 2)  # spawned
    assert proc.returncode == 2 and len(proc.stderr) < 500, proc.stderr[:3000]
    assert proc.stderr.startswith("goldenticket: error: ") and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert f"re-runs the main script, {HERE / '<stdin>'}, which is not a file" in proc.stderr


@pytest.mark.slow
def test_a_script_read_from_standard_input_runs_in_one_process(tmp_path):
    """The check that another process rebuilds the env starts a new interpreter, not the script."""
    proc = _from_standard_input(tmp_path, "byo_example:make_policy", TASK, 1)
    assert proc.returncode == 0 and "ticket" not in proc.stderr, proc.stderr[-3000:]


def _numbers(results) -> list[tuple]:
    return [(r.seed, r.success, r.ret, r.length, r.cause, r.digest) for r in results]


@pytest.mark.slow
def test_workers_give_the_episodes_of_one_process_and_go_on_after_a_failing_shard():
    task, seeds = get_task(TASK, max_steps=30), seeds_in("heldout", 10)
    episodes = [Episode(source, seed) for seed in seeds for source in (Gaussian(), Gaussian(1))]
    with Engine("byo_example:make_policy", task, shard_size=3) as engine:
        here = engine.evaluate(episodes)
    broken = get_task("byo_example:make_broken_step_env", max_steps=30)
    with Engine("byo_example:make_policy", [task, broken], workers=2, shard_size=3) as engine:
        with pytest.raises(UserError, match="the robot fell over"):
            engine.evaluate(episodes, task=broken.name)
        starts = []
        in_workers = engine.evaluate(episodes, lambda start, _: starts.append(start))
    assert _numbers(in_workers) == _numbers(here) and starts == [0, 3, 6, 9, 12, 15, 18]

"""An env step or a policy call that never returns ends the run in one line naming the task, the seed
and the call, in one process, in worker processes and on Ray; the episodes finished before it stay in
the run store and a rerun resumes. A crash in an env's C code prints where it happened. The hanging
runs go in their own process, so that a limit that never fires fails its test instead of hanging it."""

import ctypes
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from byo_example import BiasedController, PointReach
from test_worker_failures import _driven, _own_process

from goldenticket.errors import UserError
from goldenticket.evaluation import Evaluator
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import CallTimedOut, Engine, Episode, rollout
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in

HERE = Path(__file__).parent
HANG = "GOLDENTICKET_TEST_HANG"  # what never returns: "step:<seed>", or "act" (on the zero ticket)
HANG_FOR = "GOLDENTICKET_TEST_HANG_FOR"  # seconds it hangs instead (a test in pytest's own process)
POLICY, TASK = "test_time_limits:make_policy", "test_time_limits:make_env"
SEEDS = seeds_in("heldout", 32)
LIMIT_NOTE = "(a slow simulator or model needs a larger one; 0: no limit)"


def _hang_until() -> float:
    """When a hang that starts now ends: HANG_FOR seconds from now, else never."""
    return time.monotonic() + float(os.environ.get(HANG_FOR, "inf"))


class HangsOnASeed(PointReach):
    """Its step sleeps forever (or HANG_FOR seconds) in the episode of the seed that HANG names."""

    def reset(self, seed=None, options=None):
        self.episode_seed, self.hang_until = seed, _hang_until()
        return super().reset(seed=seed, options=options)

    def step(self, action):
        while os.environ.get(HANG) == f"step:{self.episode_seed}" and time.monotonic() < self.hang_until:
            time.sleep(min(3600.0, self.hang_until - time.monotonic()))  # one long sleep, not short ones
        return super().step(action)


class CrashesOnASeed(HangsOnASeed):
    """Its step crashes the process (a segfault, as a simulator's C code can) on the seed HANG names."""

    def step(self, action):
        if os.environ.get(HANG) == f"crash:{self.episode_seed}":
            ctypes.string_at(0)
        return super().step(action)


class HangsOnTheZeroTicket(BiasedController):
    """Its act loops forever (or HANG_FOR seconds), in Python, when HANG says so and the noise is the
    zero ticket."""

    name = "hangs-on-the-zero-ticket"

    def __init__(self):
        self.hang_until = _hang_until()

    def act(self, obs, noise):
        while os.environ.get(HANG) == "act" and not noise.any() and time.monotonic() < self.hang_until:
            pass
        return super().act(obs, noise)


def make_env():
    return HangsOnASeed()


def make_crashing_env():
    return CrashesOnASeed()


def make_policy():
    return HangsOnTheZeroTicket()


def evaluate_into(store: str, workers: int, step_timeout: float | None = 1.0) -> None:
    """16 base episodes, then 16 on the zero ticket, in one engine call of shards of 4 episodes."""
    zero = Constant(np.zeros((4, 2), np.float32))
    with Engine(POLICY, get_task(TASK, max_steps=5), workers=workers, shard_size=4,
                step_timeout=step_timeout) as engine:
        Evaluator(engine, RunStore(store)).run([("base", Gaussian(), SEEDS[:16]), ("zero", zero, SEEDS[16:])])


def _hung(call: str, hang: str) -> subprocess.CompletedProcess:
    """`call` of this module in a process of its own with HANG set (test_worker_failures' `_driven`)."""
    return _driven(call, "test_time_limits", env=os.environ | {HANG: hang})


def _episodes(store: Path) -> list[tuple]:
    with sqlite3.connect(store) as con:
        return con.execute("SELECT ticket_id, seed, success, ret, length, wall_time FROM episodes "
                           "ORDER BY seed, ticket_id").fetchall()


def _arms(rows: list[tuple]) -> dict[str, int]:
    return {arm: sum(row[0] == arm for row in rows) for arm in ("base", "zero")}


HANGS = {  # what hangs -> (its line, the episodes recorded before it: base, zero)
    f"step:{SEEDS[20]}": (f"task {TASK!r}: step() on seed {SEEDS[20]}", {"base": 16, "zero": 4}),
    "act": (f"policy 'hangs-on-the-zero-ticket': act() on task {TASK!r}, seeds "
            f"{', '.join(map(str, SEEDS[16:20]))}", {"base": 16, "zero": 0}),
}


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("hang", list(HANGS))
def test_a_call_that_never_returns_ends_the_run_in_one_line_and_a_rerun_resumes(tmp_path, monkeypatch, hang,
                                                                                workers):
    store = tmp_path / "run.sqlite"
    proc = _hung(f"evaluate_into({str(store)!r}, {workers})", hang)
    call, recorded = HANGS[hang]
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == f"{call} did not return within step_timeout 1 s {LIMIT_NOTE}\n"
    before = _episodes(store)
    assert _arms(before) == recorded  # the shards that finished before it, shard 4 or 5 on
    monkeypatch.delenv(HANG, raising=False)
    evaluate_into(str(store), workers=1, step_timeout=None)  # the hang gone: it resumes, in this process
    after = _episodes(store)
    assert _arms(after) == {"base": 16, "zero": 16}
    assert set(before) <= set(after)  # read back, not run again (their wall times unchanged)


def test_a_step_that_sleeps_forever_ends_in_one_line(monkeypatch):
    monkeypatch.setenv(HANG, f"step:{SEEDS[1]}")
    monkeypatch.setenv(HANG_FOR, "20")  # here, in pytest's process, not quite forever
    before = signal.getsignal(signal.SIGALRM)
    with pytest.raises(CallTimedOut) as caught:
        rollout(make_policy(), get_task(TASK, max_steps=5), [Episode(Gaussian(), s) for s in SEEDS[:3]],
                step_timeout=0.2)
    assert str(caught.value) == (f"task {TASK!r}: step() on seed {SEEDS[1]} did not return within "
                                 f"step_timeout 0.2 s {LIMIT_NOTE}")
    assert caught.value.as_flags().startswith(f"task {TASK!r}: step() on seed {SEEDS[1]} did not return "
                                              "within --step-timeout 0.2 s")
    assert signal.getsignal(signal.SIGALRM) is before and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_a_policy_looping_forever_outside_the_main_thread_ends_in_one_line(monkeypatch):
    """Off the main thread no timer signal can reach the call: a watcher thread ends it."""
    monkeypatch.setenv(HANG, "act")
    monkeypatch.setenv(HANG_FOR, "20")
    zero, raised = Constant(np.zeros((4, 2), np.float32)), []

    def run():
        try:
            rollout(make_policy(), get_task(TASK, max_steps=5), [Episode(zero, s) for s in SEEDS[:2]],
                    step_timeout=0.2)
        except UserError as exc:
            raised.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(timeout=30)
    assert not thread.is_alive() and [str(e) for e in raised] == [
        f"policy 'hangs-on-the-zero-ticket': act() on task {TASK!r}, seeds {SEEDS[0]}, {SEEDS[1]} did not "
        f"return within step_timeout 0.2 s {LIMIT_NOTE}"]


@pytest.mark.slow
def test_a_search_whose_step_hangs_stops_in_one_line_and_the_same_command_resumes(tmp_path):
    """From the command line, in one process; the rerun, without the hang, keeps the default limit."""
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "goldenticket.cli", "search", "--policy", POLICY, "--task", TASK,
            "--workers", "1", "--max-steps", "5", "--method", "rs", "--optimizer", "batch_size=5", "--budget",
            "40", "--search-seeds", "4", "--heldout", "24", "--top-k", "1", "--validation-seeds", "0",
            "--out", str(out)]
    hung = SEEDS[10]  # in the second shard of 16: base and zero on seeds 0-7 come first
    proc = _own_process(argv + ["--step-timeout", "1"], timeout=120, cwd=HERE,
                        env=os.environ | {HANG: f"step:{hung}"})
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines()[-1] == (f"goldenticket: error: task {TASK!r}: step() on seed {hung} did "
                                            "not return within --step-timeout 1 s (a slow simulator or "
                                            "model needs a larger one; 0: no limit)")
    assert "Traceback" not in proc.stderr
    before = _episodes(out / "run.sqlite")
    assert {row[1] for row in before} == set(SEEDS[:8]) and _arms(before) == {"base": 8, "zero": 8}
    env = {k: v for k, v in os.environ.items() if k != HANG}
    rerun = _own_process(argv, timeout=300, cwd=HERE, env=env)
    assert rerun.returncode == 0, rerun.stderr
    assert set(before) <= set(_episodes(out / "run.sqlite")) and (out / "summary.json").exists()


@pytest.mark.slow
def test_a_segfault_in_an_env_prints_where_it_happened(tmp_path):
    """In one process the crash kills the run: its traceback names the env's call that crashed."""
    crashed = SEEDS[2]
    argv = [sys.executable, "-m", "goldenticket.cli", "evaluate", "--policy", POLICY, "--task",
            "test_time_limits:make_crashing_env", "--workers", "1", "--max-steps", "5", "--seeds",
            f"{SEEDS[0]}:{SEEDS[4]}"]
    proc = _own_process(argv, timeout=120, cwd=HERE, env=os.environ | {HANG: f"crash:{crashed}"})
    assert proc.returncode == -signal.SIGSEGV
    assert "Fatal Python error: Segmentation fault" in proc.stderr
    assert f'File "{HERE / "test_time_limits.py"}", line ' in proc.stderr and " in step" in proc.stderr


@pytest.mark.ray
@pytest.mark.xdist_group("ray")
def test_a_policy_call_that_never_returns_on_a_ray_actor_ends_in_one_line(monkeypatch):
    ray = pytest.importorskip("ray")
    monkeypatch.setenv(HANG, "act")  # Ray's actors start with this process's environment
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, (str(HERE), os.environ.get("PYTHONPATH")))))
    zero = Constant(np.zeros((4, 2), np.float32))
    episodes = [Episode(Gaussian(), s) for s in SEEDS[:4]] + [Episode(zero, s) for s in SEEDS[4:8]]
    try:
        with Engine(POLICY, get_task(TASK, max_steps=5), workers=1, shard_size=4, backend="ray",
                    step_timeout=1) as engine, pytest.raises(CallTimedOut) as caught:
            engine.evaluate(episodes)
    finally:
        ray.shutdown()
    assert str(caught.value) == (f"policy 'hangs-on-the-zero-ticket': act() on task {TASK!r}, seeds "
                                 f"{', '.join(map(str, SEEDS[4:8]))} did not return within step_timeout 1 s "
                                 f"{LIMIT_NOTE}")

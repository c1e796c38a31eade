"""Runs killed, interrupted, doubled, starved of disk or fed damaged files: nothing computed is lost,
and every failure is one clear line with exit code 2 (or 128 + signal for a stop)."""

import contextlib
import io
import json
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from goldenticket.cli import main
from goldenticket.policies import BUNDLED_DIR

SEARCH = ["search", "--policy", "metaworld/reach-v3/flow", "--task", "metaworld/reach-v3",
          "--method", "cem-racing", "--budget", "24", "--search-seeds", "5", "--validation-seeds", "3",
          "--heldout", "8", "--top-k", "2", "--stop-after-perfect", "0", "--max-steps", "30"]
# base and zero, search, validation of 6 and zero, top 2 (the zero ticket beside them shares the zero arm's)
BASELINES, TOTAL = 16, 16 + 24 + 21 + 16


def _command(out: Path, workers: int = 1) -> list[str]:
    return [sys.executable, "-m", "goldenticket.cli", *SEARCH, "--workers", str(workers), "--out", str(out)]


def _here(command: list[str]) -> subprocess.CompletedProcess:
    """`command` run by the CLI's main in this process: the runs that are neither stopped nor doubled."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(command[3:])  # past `python -m goldenticket.cli`
    return subprocess.CompletedProcess(command, code, stdout.getvalue(), stderr.getvalue())


def _run(out: Path, workers: int = 1) -> subprocess.CompletedProcess:
    return _here(_command(out, workers))


def _numbers(out: Path) -> dict:
    """summary.json without the paths, which name the folder."""
    summary = json.loads((out / "summary.json").read_text())
    for entry in [summary["best"], *summary["tickets"]]:
        entry.pop("ticket_path")
    return summary


def _recorded(out: Path) -> int:
    try:
        with sqlite3.connect(f"file:{out / 'run.sqlite'}?mode=ro", uri=True, timeout=5) as con:
            return con.execute("SELECT count(*) FROM episodes").fetchone()[0]
    except sqlite3.Error:
        return 0


def _stop_after(out: Path, episodes: int, sig: int, workers: int = 1) -> tuple[int, str, int]:
    """Start a run, send `sig` once `episodes` are recorded; (exit code, stderr, episodes kept)."""
    proc = subprocess.Popen(_command(out, workers), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    while proc.poll() is None and _recorded(out) < episodes:
        time.sleep(0.02)
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=120)
    return proc.returncode, stderr, _recorded(out)


def _one_error_line(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 2, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "error" in line.lower()]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return errors[0]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    """An uninterrupted run: its numbers and what it printed on stderr (the progress bars)."""
    out = tmp_path_factory.mktemp("reference")
    proc = _run(out)
    assert proc.returncode == 0 and _recorded(out) == TOTAL
    return {"numbers": _numbers(out), "stderr": proc.stderr, "out": out}


@pytest.mark.slow
def test_progress_bars_never_count_past_their_total(reference):
    counts = [(int(a), int(b)) for a, b in re.findall(r"\| (\d+)/(\d+) \[", reference["stderr"])]
    assert counts and all(done <= total for done, total in counts), counts


@pytest.mark.slow
@pytest.mark.parametrize("episodes, workers", [(1, 1), (BASELINES + 1, 2), (BASELINES + 24, 1),
                                               (BASELINES + 42, 2)],
                         ids=["baselines", "search", "validation", "top tickets"])
def test_kill_9_then_rerun_gives_the_same_numbers(reference, tmp_path, episodes, workers):
    code, _, kept = _stop_after(tmp_path, episodes, signal.SIGKILL, workers)
    assert code == -signal.SIGKILL and kept <= TOTAL  # killed mid-run: after all episodes at the latest
    assert _run(tmp_path, workers).returncode == 0
    assert _numbers(tmp_path) == reference["numbers"]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_and_sigterm_stop_with_one_line_and_resume(reference, tmp_path, sig):
    code, stderr, kept = _stop_after(tmp_path, BASELINES, sig)
    assert code == 128 + sig and "Traceback" not in stderr, stderr
    assert f"stopped by {signal.Signals(sig).name}" in stderr.splitlines()[-1]
    assert 0 < kept < TOTAL
    assert _run(tmp_path).returncode == 0
    assert _numbers(tmp_path) == reference["numbers"]


@pytest.mark.slow
def test_two_processes_on_one_out_both_finish_with_the_same_numbers(reference, tmp_path):
    procs = [subprocess.Popen(_command(tmp_path), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    for proc in procs:
        assert proc.wait(timeout=300) == 0, proc.stderr.read()
    assert _numbers(tmp_path) == reference["numbers"]


@pytest.mark.slow
def test_two_processes_with_different_options_on_one_out_one_is_refused(tmp_path):
    commands = [_command(tmp_path), _command(tmp_path) + ["--seed", "1"]]
    procs = [subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for c in commands]
    codes = sorted(proc.wait(timeout=300) for proc in procs)
    assert codes == [0, 2]


@pytest.fixture
def disk(tmp_path):
    """A 2 MiB tmpfs of our own, to fill or make read-only."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)],
                      capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def _fill(disk: Path) -> Path:
    ballast = disk / "ballast"
    with ballast.open("wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError:
            pass
    return ballast


@pytest.mark.slow
def test_disk_filling_mid_run_is_one_line_and_a_rerun_resumes(reference, disk):
    out = disk / "run"
    proc = subprocess.Popen(_command(out), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while proc.poll() is None and _recorded(out) < BASELINES:
        time.sleep(0.02)
    ballast = _fill(disk)
    _, stderr = proc.communicate(timeout=300)
    line = _one_error_line(subprocess.CompletedProcess([], proc.returncode, "", stderr))
    assert "full" in line or "No space" in line, line
    assert BASELINES <= _recorded(out) < TOTAL
    ballast.unlink()
    assert _run(out).returncode == 0
    assert _numbers(out) == reference["numbers"]


@pytest.mark.slow
def test_read_only_out_is_one_line(disk):
    subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
    assert "Read-only" in _one_error_line(_run(disk / "run"))


@pytest.mark.slow
def test_out_that_is_or_lies_under_a_file_is_one_line(tmp_path):
    (tmp_path / "file").write_text("x")
    assert "is a file" in _one_error_line(_run(tmp_path / "file"))
    assert "Not a directory" in _one_error_line(_run(tmp_path / "file" / "run"))


@pytest.mark.slow
def test_damaged_store_is_one_line(tmp_path, reference):
    store = tmp_path / "run.sqlite"
    data = bytearray((reference["out"] / "run.sqlite").read_bytes())
    data[2 * 4096 : 3 * 4096] = b"\xff" * 4096  # the third page: the episodes table
    store.write_bytes(bytes(data))
    assert "move it away" in _one_error_line(_run(tmp_path))


@pytest.mark.slow
@pytest.mark.parametrize("damage, says", [
    ("UPDATE episodes SET ret = 'lots' WHERE rowid = 1", "non-numeric ret"),
    ("UPDATE config SET value = 'not json'", "config is not JSON"),
], ids=["return", "config"])
def test_a_store_value_of_the_wrong_type_is_one_line(reference, tmp_path, damage, says):
    store = tmp_path / "run.sqlite"
    shutil.copy(reference["out"] / "run.sqlite", store)
    with sqlite3.connect(store) as con:
        con.execute(damage)
    line = _one_error_line(_run(tmp_path))
    assert says in line and f"{store}:" in line, line


def test_a_truncated_policy_file_is_one_line(tmp_path, capsys):
    folder = tmp_path / "policy"
    shutil.copytree(BUNDLED_DIR / "metaworld/reach-v3/flow", folder)
    weights = folder / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[:-100])
    code = main(["evaluate", "--policy", str(folder), "--task", "metaworld/reach-v3",
                 "--seeds", "1000000:1000002"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"goldenticket: error: {weights}: not a valid safetensors file")
    assert len(err.splitlines()) == 1, err


@pytest.mark.slow
@pytest.mark.parametrize("options", [{"--budget": "3", "--search-seeds": "20"},  # racing's 1st tier: 4
                                     {"--stop-after-perfect": "-1"}, {"--workers": "0"},
                                     {"--max-steps": "0"}, {"--seed": "-1"}], ids=str)
def test_options_are_checked_before_any_episode(tmp_path, options):
    out = tmp_path / "run"
    command = _command(out)
    for option, value in options.items():
        if option in command:
            command[command.index(option) + 1] = value
        else:
            command += [option, value]
    _one_error_line(_here(command))
    assert not out.exists()

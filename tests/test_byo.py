"""A policy and an environment of the user's, named `module:factory`, through the CLI, the API
and the workers, with the same checks and results as the bundled ones."""

import json
import re
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import goldenticket
from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import load_policy
from goldenticket.rollout import NONFINITE, Episode, rollout
from goldenticket.tasks import get_task, seeds_in

HERE = Path(__file__).parent
SEARCH = ["search", "--policy", "byo_example:make_policy", "--task", "byo_example:make_env",
          "--max-steps", "30", "--budget", "400", "--search-seeds", "20", "--validation-seeds", "20",
          "--heldout", "50", "--top-k", "2"]


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "goldenticket.cli", *argv], capture_output=True,
                          text=True, timeout=300, cwd=HERE)


@pytest.mark.slow
def test_search_and_evaluate_from_the_cli_resume_and_agree_with_the_api(tmp_path, capsys):
    sys.path.insert(0, str(HERE))
    out = tmp_path / "cli"
    assert main([*SEARCH, "--workers", "2", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["base"]["n"] == 50 and summary["best"]["golden"]
    assert main([*SEARCH, "--workers", "1", "--out", str(out)]) == 0  # resumes
    assert json.loads((out / "summary.json").read_text()) == summary
    ticket = summary["best"]["ticket_path"]
    capsys.readouterr()
    assert main(["evaluate", "--policy", "byo_example:make_policy", "--task", "byo_example:make_env",
                 "--max-steps", "30", "--ticket", ticket, "--seeds", "1000100:1000200", "--workers", "1",
                 "--plot", str(tmp_path / "e.png")]) == 0
    assert "Golden ticket" in capsys.readouterr().out  # on fresh seeds

    api = goldenticket.search("byo_example:make_policy", "byo_example:make_env", tmp_path / "api",
                              max_steps=30, budget=400, search_seeds=20, validation_seeds=20, heldout=50,
                              top_k=2, workers=1)
    assert [t.id for t in api.tickets] == [t["ticket_id"] for t in summary["tickets"]]
    assert api.to_dict() == json.loads((tmp_path / "api" / "summary.json").read_text())
    rows = goldenticket.evaluate("byo_example:make_policy", "byo_example:make_env", [ticket],
                                 range(1000100, 1000110), max_steps=30, workers=1)
    assert rows["base"].rate.n == 10 and len(rows) == 3


@pytest.mark.slow
def test_the_api_takes_objects_and_a_success_predicate(tmp_path):
    sys.path.insert(0, str(HERE))
    import byo_example

    options = dict(max_steps=30, budget=160, search_seeds=20, validation_seeds=20, heldout=30, top_k=1)
    by_name = goldenticket.search("byo_example:make_policy", "byo_example:make_env", tmp_path / "n",
                                  workers=1, **options)
    by_object = goldenticket.search(byo_example.BiasedController(), byo_example.make_silent_env,
                                    tmp_path / "o", success=byo_example.within_reach, workers=2, **options)
    assert by_object.task == "byo_example:make_silent_env" and by_object.run.policy == "biased-controller"
    assert by_object.base == by_name.base and by_object.zero == by_name.zero
    assert by_object.best.heldout.rate == by_name.best.heldout.rate
    rows = goldenticket.evaluate(byo_example.BiasedController(), byo_example.make_silent_env,
                                 [by_object.best.path], range(1000100, 1000120),
                                 success="byo_example:within_reach", max_steps=30, workers=1)
    assert rows["base"].rate.n == 20 and len(rows) == 3
    with pytest.raises(UserError, match="cannot be sent to a worker process"):
        goldenticket.search(byo_example.BiasedController(), lambda: byo_example.PointReach(),
                            tmp_path / "l", workers=1, **options)


def test_the_builtin_task_through_the_gymnasium_door_gives_the_same_episodes():
    sys.path.insert(0, str(HERE))
    policy = load_policy("metaworld/reach-v3/flow")
    episodes = [Episode(source, s) for s in seeds_in("heldout", 6)
                for source in (Gaussian(0), Constant(np.full(policy.noise_shape, 0.3, np.float32)))]
    builtin = rollout(policy, get_task("metaworld/reach-v3"), episodes)
    generic = rollout(policy, get_task("byo_example:make_metaworld_reach", 150), episodes)
    key = [(r.success, r.length, r.ret) for r in builtin]
    assert key == [(r.success, r.length, r.ret) for r in generic]
    assert 0 < sum(r.success for r in builtin) < len(builtin)


@pytest.mark.slow
def test_users_mistakes_are_one_line_and_exit_2(tmp_path, capsys):
    base = ["evaluate", "--seeds", "1000000:1000004", "--max-steps", "30", "--workers", "1",
            "--plot", str(tmp_path / "e.png")]
    policy, env = ["--policy", "byo_example:make_policy"], ["--task", "byo_example:make_env"]
    cases = {
        "non-deterministic reset": [*base, *policy, "--task", "byo_example:make_unseeded_env"],
        "wrong action shape": [*base, *env, "--policy", "byo_example:make_wrong_shape_policy"],
        "NaN actions": [*base, *env, "--policy", "byo_example:make_nan_policy"],
        "no success signal": [*base, *policy, "--task", "byo_example:make_silent_env"],
        "module not found": [*base, *env, "--policy", "no_such_module:make"],
        "factory not found": [*base, *env, "--policy", "byo_example:no_such_factory"],
        "Meta-World's own env": [*base, *policy, "--task", "byo_example:make_metaworld_gym"],
    }
    lines = {name: _error_line(capsys, argv) for name, argv in cases.items()}
    assert "ignore reset(seed=)" in lines["Meta-World's own env"]


@pytest.mark.slow
def test_readme_example_runs_as_written(tmp_path):
    """README's mine.py and the docs' Python API script for it, run as a user would: objects go to
    spawned workers, and the run names the task by the script's module, as the CLI does. Without
    its `if __name__ == "__main__":` guard the script stops at once, saying so."""
    section = (HERE.parent / "README.md").read_text().split("## Use your own policy")[1]
    mine = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    how_to = (HERE.parent / "docs" / "how-to" / "own-policy.md").read_text().split("## From Python")[1]
    script = re.findall(r"```python\n(.*?)```", how_to, re.S)[0]
    (tmp_path / "mine.py").write_text(mine)
    (tmp_path / "run_api.py").write_text(script)
    proc = subprocess.run([sys.executable, "run_api.py"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("golden ")
    summary = json.loads((tmp_path / "runs" / "mine-py" / "summary.json").read_text())
    assert summary["task"] == "mine:make_env" and summary["base"]["n"] == 100

    unguarded = "".join(line.strip() + "\n" for line in script.splitlines() if "__main__" not in line)
    (tmp_path / "unguarded.py").write_text(unguarded.replace("runs/mine-py", "runs/unguarded"))
    proc = subprocess.run([sys.executable, "unguarded.py"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 1 and "if __name__ == '__main__':" in proc.stderr.splitlines()[-1]


def _line_of(code: str) -> str:
    """`byo_example.py:N`, N the line of byo_example.py holding `code`."""
    lines = (HERE / "byo_example.py").read_text().splitlines()
    return f"{HERE / 'byo_example.py'}:{next(i for i, line in enumerate(lines, 1) if code in line)}"


def _error_line(capsys, argv: list[str]) -> str:
    """Run the CLI here; its one error line (exit 2, no traceback)."""
    sys.path.insert(0, str(HERE))
    code = main(argv)
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err, err
    return errors[0]


EVALUATE = ["evaluate", "--policy", "byo_example:make_policy", "--task", "byo_example:make_env", "--seeds",
            "1000000:1000004", "--max-steps", "30", "--workers", "1"]
FAULTS = {  # the user's code at fault: (options replacing EVALUATE's, what its one line says)
    "complex actions": (["--policy", "byo_example:make_complex_policy"], "actions of dtype complex128"),
    "object actions": (["--policy", "byo_example:make_object_policy"], "actions of dtype object"),
    "str actions": (["--policy", "byo_example:make_str_policy"], "actions of dtype <U"),
    "act raises": (["--policy", "byo_example:make_raising_policy"],
                   "policy 'biased-controller': act() failed at " + _line_of('obs["velocity"]') +
                   ": KeyError: 'velocity'"),
    "reset raises": (["--task", "byo_example:make_broken_reset_env"],
                     f"reset() failed at {_line_of('no table in the scene')}: RuntimeError: no table"),
    "step raises": (["--task", "byo_example:make_broken_step_env"],
                    f"step() failed at {_line_of('the robot fell over')}: RuntimeError: the robot fell over"),
    "success predicate raises": (["--task", "byo_example:make_silent_env", "--success",
                                  "byo_example:broken_predicate"],
                                 "step() failed at " + _line_of('obs["distance"]') + ": KeyError:"),
    "fingerprint raises": (["--policy", "byo_example:make_raising_fingerprint_policy"],
                           f"fingerprint() failed at {_line_of('1 / 0')}: ZeroDivisionError"),
    "fingerprint not a string": (["--policy", "byo_example:make_int_fingerprint_policy"],
                                 "fingerprint() must return a string, got int"),
}


def _evaluate(*options: str) -> list[str]:
    """EVALUATE with `options` (option, value, ...) in place of its own, or added."""
    argv = list(EVALUATE)
    for option, value in zip(options[::2], options[1::2], strict=True):
        if option in argv:
            argv[argv.index(option) + 1] = value
        else:
            argv += [option, value]
    return argv


@pytest.mark.slow
@pytest.mark.parametrize("fault", FAULTS)
def test_a_fault_in_the_users_code_is_one_line_naming_it(capsys, fault):
    options, says = FAULTS[fault]
    assert says in _error_line(capsys, _evaluate(*options))


@pytest.mark.slow
def test_a_fault_in_a_worker_process_is_the_same_line_and_verbose_shows_its_traceback(capsys):
    policy = ("--policy", "byo_example:make_raising_policy")
    here = _error_line(capsys, _evaluate(*policy))
    assert _error_line(capsys, _evaluate(*policy, "--workers", "2")) == here
    assert main(["--verbose", *_evaluate(*policy)]) == 2
    verbose = capsys.readouterr().err
    assert verbose.splitlines()[-1] == here
    assert "Traceback" in verbose and 'return obs["velocity"]' in verbose


@pytest.mark.slow
def test_a_policy_rarely_non_finite_gets_a_verdict_counting_those_episodes(capsys, tmp_path):
    """Its rare non-finite episodes are failures, counted per arm in the table and summary.json;
    the base alone over --max-nonfinite is no stop: the zero ticket's episodes stay finite."""
    sys.path.insert(0, str(HERE))
    argv = _evaluate("--policy", "byo_example:make_rare_nan_policy", "--seeds", "1000000:1000200")
    assert main([*argv, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert 0 < rows["base"]["nonfinite_episodes"] <= 0.1 * 200 and rows["zero"]["nonfinite_episodes"] >= 0
    assert main(argv) == 0
    header = capsys.readouterr().out.splitlines()[0]
    assert "non-finite" in header
    assert main([*argv, "--max-nonfinite", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == rows

    summary = goldenticket.search("byo_example:make_rare_nan_policy", "byo_example:make_env", tmp_path,
                                  max_steps=30, budget=160, heldout=200, validation_seeds=20, top_k=2,
                                  workers=1)
    assert summary.base.nonfinite == rows["base"]["nonfinite_episodes"]  # the same episodes
    assert all("nonfinite_episodes" in t for t in summary.to_dict()["tickets"])


@pytest.mark.slow
def test_a_policy_always_non_finite_stops_at_its_first_heldout_shard(capsys, tmp_path):
    line = _error_line(capsys, ["search", "--policy", "byo_example:make_nan_policy", "--task",
                                "byo_example:make_env", "--max-steps", "30", "--heldout", "50", "--workers",
                                "1", "--out", str(tmp_path)])
    # the first shard holds base and zero of the first 8 seeds (new episodes run in seed order)
    assert "NaN or infinite actions in 8 of the 50 held-out episodes of base" in line, line
    assert "at step 0" in line
    with sqlite3.connect(tmp_path / "run.sqlite") as con:
        assert con.execute("SELECT count(*), min(cause) FROM episodes").fetchone() == (16, NONFINITE)


@pytest.mark.slow
def test_an_env_unseeded_only_in_pool_workers_stops_the_run_in_one_line(tmp_path, capsys):
    """It passes the seed checks of one process and of a spawned one; the episodes' own initial
    states, checked as they come back from the workers, give it away."""
    argv = ["search", "--policy", "byo_example:make_policy", "--task",
            "byo_example:make_unseeded_in_pools_env", "--max-steps", "30", "--budget", "40",
            "--heldout", "20", "--validation-seeds", "0", "--top-k", "1"]
    sys.path.insert(0, str(HERE))
    assert main([*argv, "--workers", "1", "--out", str(tmp_path / "1")]) == 0  # one process keeps its seeds
    error = _error_line(capsys, [*argv, "--workers", "2", "--out", str(tmp_path / "2")])
    assert re.search(r"reset\(seed=100000\d+\) does not fix the initial state in worker processes", error)
    assert not (tmp_path / "2" / "summary.json").exists()

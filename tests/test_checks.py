"""The named checks every run makes of its policy and task before any episode (goldenticket.checks),
and `goldenticket check`, which prints them."""

import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest
from byo_example import BiasedController, IgnoresNoise, WideActions

import goldenticket
from goldenticket import checks
from goldenticket.cli import main
from goldenticket.config import SearchConfig
from goldenticket.errors import UserError
from goldenticket.job.plan import checked_tasks
from goldenticket.tasks import GymTask, get_task
from goldenticket.tasks.base import episodes
from goldenticket.tasks.metaworld import MetaWorldEnv

NAMES = ["policy and task agree", "the policy answers its noise", "seeds fix initial states",
         "same actions, same episode"]


@pytest.fixture
def here_only(monkeypatch):
    """The fresh process's episodes taken in this one (a spawned process costs a second or more; the
    tests of the fresh process spawn one)."""
    monkeypatch.setattr(checks, "episodes_in_another_process",
                        lambda task: episodes(task, checks.CHECK_SEEDS, checks.CHECK_STEPS))


@pytest.mark.slow
def test_a_bundled_policy_passes_every_check_on_its_task(capsys):
    assert main(["check", "--policy", "metaworld/reach-v3/flow", "--task", "metaworld/reach-v3"]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert [line.split(":")[0] for line in lines] == [f"pass  {name}" for name in NAMES]
    assert "in another process" in lines[2] and err == ""


def test_every_check_passes_on_a_users_policy_and_env(capsys, here_only):
    assert main(["check", "--policy", "byo_example:make_policy", "--task", "byo_example:make_env"]) == 0
    out, err = capsys.readouterr()
    assert [line.split(":")[0] for line in out.splitlines()] == [f"pass  {name}" for name in NAMES]
    assert err == ""


def test_failed_checks_print_their_line_and_exit_2_in_one_line(capsys):
    argv = ["check", "--policy", "byo_example:make_noise_ignoring_policy", "--task",
            "byo_example:make_unseeded_env"]
    assert main(argv) == 2
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert [line.split(":")[0] for line in lines] == ["pass  policy and task agree"] + [
        f"FAIL  {name}" for name in NAMES[1:]]
    assert "ignores its noise" in lines[1] and "reset(seed=0) does not fix the initial state" in lines[2]
    assert err == ("goldenticket: error: 3 of 4 checks failed: the policy answers its noise; seeds fix "
                   "initial states; same actions, same episode\n")


def test_an_env_whose_reset_ignores_its_seed_fails_both_task_checks():
    first, second = checks.results(get_task("byo_example:make_unseeded_env"))
    assert not first.passed and not second.passed
    assert first.detail.startswith("task 'byo_example:make_unseeded_env': reset(seed=0) does not fix the "
                                   "initial state (the same seed gave a different observation in the same "
                                   "env after other episodes: its 'goal', 'pos' differ)")
    assert "the same seed (0) and actions gave different observations" in second.detail


def test_an_env_seeded_otherwise_in_a_fresh_process_fails_there():
    first, second = checks.results(get_task("byo_example:make_per_process_env"))
    assert "does not fix the initial state (the same seed gave a different observation in another " \
           "process" in first.detail
    assert not second.passed


def test_a_meta_world_task_is_checked_like_any_other(monkeypatch, tiny_policies):
    """A Meta-World env whose resets drift fails the job's checks (its task once passed any)."""
    drift = iter(range(10**6))
    original = MetaWorldEnv.reset

    def drifting(self, seed):
        return original(self, seed) + np.float32(next(drift))

    monkeypatch.setattr(MetaWorldEnv, "reset", drifting)
    cfg = SearchConfig("test/flow", "metaworld/pick-place-v3")
    with pytest.raises(UserError, match=r"^task 'metaworld/pick-place-v3': reset\(seed=0\) does not fix"):
        checked_tasks(tiny_policies["flow"], cfg)


def test_a_policy_that_ignores_its_noise_fails_in_one_line():
    subject = checks.Subject(get_task("byo_example:make_env"), IgnoresNoise())
    with pytest.raises(UserError, match=r"^policy 'ignores-noise' ignores its noise: 4 different noise "
                                        r"arrays gave the same actions .* \(it has no golden tickets\)$"):
        checks.the_policy_answers_its_noise(subject)
    listens = checks.Subject(get_task("byo_example:make_env"), BiasedController())
    assert checks.the_policy_answers_its_noise(listens).startswith("4 different noise arrays")


def test_the_job_refuses_a_policy_that_ignores_its_noise_before_any_episode(tmp_path):
    with pytest.raises(UserError, match="ignores its noise"):
        goldenticket.search(IgnoresNoise(), "byo_example:make_env", tmp_path / "run", max_steps=10,
                            budget=20, search_seeds=2, heldout=4, workers=1)
    assert not (tmp_path / "run").exists()


def test_a_policy_for_another_task_fails_agreement(tiny_policies):
    wide = checks.Subject(get_task("byo_example:make_env"), WideActions())
    with pytest.raises(UserError, match=r"^policy 'biased-controller' acts with 3 numbers and task "
                                        r"'byo_example:make_env' takes 2"):
        checks.policy_and_task_agree(wide)
    states = checks.Subject(get_task("byo_example:make_env"), tiny_policies["flow"])
    with pytest.raises(UserError, match=r"sees state vectors \[B, 39\], got observations with keys"):
        checks.policy_and_task_agree(states)


def test_a_tasks_note_on_this_machine_comes_before_its_checks(here_only, capsys):
    """As robomimic's tasks say where OpenBLAS's kernels move their numbers."""
    @dataclass(frozen=True)
    class Noted(GymTask):
        def note(self):
            print("note: this machine", file=sys.stderr)

    said = [r.passed for r in checks.results(Noted("byo_example:make_env"))]
    assert said == [True, True] and capsys.readouterr().err == "note: this machine\n"


@pytest.mark.slow
def test_a_built_in_task_is_checked_from_a_script_read_from_standard_input(tmp_path):
    """Its fresh process is a new interpreter, not a spawn that would re-run the main script."""
    script = ("import goldenticket\n"
              "rows = goldenticket.evaluate('metaworld/reach-v3/flow', 'metaworld/reach-v3', "
              "seeds=range(1000000, 1000002), workers=1)\n"
              "print(sorted(rows))\n")
    done = subprocess.run([sys.executable, "-"], input=script, capture_output=True, text=True, cwd=tmp_path,
                          timeout=300)
    assert done.returncode == 0 and done.stdout == "['base', 'zero']\n", done.stderr

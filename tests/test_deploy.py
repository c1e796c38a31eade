"""Deploying a ticket as it was found: any policy's batch, one identity however the policy is
reached, and the settings a ticket was found under reused (or contradicted with one line)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import goldenticket
from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.noise import Constant
from goldenticket.policies import TicketedPolicy, deploy, identity, load_policy
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task
from goldenticket.tasks.base import stack

README = (Path(__file__).parents[1] / "README.md").read_text()
EXAMPLES = Path(__file__).parents[1] / "examples"


def _readme_block(after: str) -> str:
    """The first python block of README after the text `after`."""
    return re.search(r"```python\n(.*?)```", README[README.index(after):], re.S).group(1)


@pytest.fixture
def mine(tmp_path, monkeypatch):
    """README's mine.py, as written there, importable from tmp_path (the current folder)."""
    (tmp_path / "mine.py").write_text(_readme_block("`mine.py`:"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("mine", None)
    import mine

    return mine


def _cli(cwd: Path, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "goldenticket.cli", *argv], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_a_deployed_policy_takes_its_batch_size_from_the_arrays_not_the_dict(mine):
    deployed = TicketedPolicy(mine.BiasedController(), np.zeros((4, 2), np.float32))
    one = {"pos": np.zeros((1, 2)), "goal": np.ones((1, 2))}
    assert deployed.act(one).shape == (1, 2, 2)  # the dict has 2 keys: not 2 action chunks
    three = {"pos": np.zeros((3, 2)), "goal": np.ones((3, 2))}
    assert deployed.act(three).shape == (3, 2, 2)
    with pytest.raises(ValueError, match="batch size"):
        deployed.act({"pos": np.zeros((1, 2)), "goal": np.ones((3, 2))})


def test_every_shipped_example_policy_deploys_on_one_observation(monkeypatch):
    pytest.importorskip("gymnasium_robotics")
    monkeypatch.syspath_prepend(str(EXAMPLES.parent))
    cases = [("metaworld/pick-place-v3/flow", "metaworld/pick-place-v3", {}),
             ("examples.fetch_push:make_policy", "examples.fetch_push:make_env", {"max_steps": 50})]
    for policy_ref, task_ref, options in cases:
        policy = load_policy(policy_ref)
        env = get_task(task_ref, **options).make_env()
        deployed = TicketedPolicy(policy, np.zeros(policy.noise_shape, np.float32))
        actions = deployed.act(stack([env.reset(1_000_000)]))
        assert actions.shape == (1, policy.n_exec, policy.noise_shape[1]), policy_ref


def test_readme_deploy_snippet_runs_and_refuses_another_policys_ticket(capsys):
    """With the bundled ticket's id for the demo's file (the demo's own runs in test_readme.py)."""
    snippet = _readme_block("## Deploy a ticket")
    demo_ticket = re.search(r'"(demo-out/tickets/\w{12}\.safetensors)"', snippet).group(1)
    namespace = {}
    exec(snippet.replace(demo_ticket, "ac7033f127b8"), namespace)
    policy, task = namespace["policy"], namespace["task"]
    ran = rollout(policy.policy, task, [Episode(Constant(policy.noise), 1_000_000)])[0]  # as evaluate runs it
    assert capsys.readouterr().out == f"(8, 4) 4 {ran.success} {ran.length}\n"
    with pytest.raises(UserError, match="was found for policy"):
        deploy("metaworld/reach-v3/flow", "ac7033f127b8")


@pytest.mark.slow
def test_one_policy_has_one_identity_from_the_cli_and_the_api(mine, tmp_path):
    assert identity(load_policy("mine:make_policy")) == identity(mine.BiasedController())
    summary = goldenticket.search(mine.BiasedController(), mine.make_env, tmp_path / "api", max_steps=30,
                                  budget=120, search_seeds=10, heldout=40, top_k=1, validation_seeds=0,
                                  workers=1).to_dict()
    ticket = summary["best"]["ticket_path"]
    # no --max-steps: the ticket's own, so the verdict's numbers come back exactly (a ticket's task
    # that is code, here mine:make_env, the user names: a ticket never runs code)
    done = _cli(tmp_path, "evaluate", "--policy", "mine:make_policy", "--task", "mine:make_env", "--ticket",
                ticket, "--seeds", "1000000:1000040", "--workers", "1", "--json")
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    assert rows["base"]["success_rate"] == summary["base"]["success_rate"]
    assert rows[summary["best"]["ticket_id"]]["success_rate"] == summary["best"]["success_rate"]


@pytest.mark.slow
def test_a_setting_that_contradicts_the_tickets_is_refused_with_both_values(mine, tmp_path, capsys):
    summary = goldenticket.search("mine:make_policy", "mine:make_env", tmp_path / "run", max_steps=30,
                                  budget=40, search_seeds=10, heldout=10, top_k=1, validation_seeds=0,
                                  workers=1)
    ticket = summary.best.path
    argv = ["evaluate", "--policy", "mine:make_policy", "--task", "mine:make_env", "--ticket", ticket,
            "--seeds", "1000000:1000010", "--workers", "1", "--max-steps", "1000"]
    capsys.readouterr()
    assert main(argv) == 2
    refused = capsys.readouterr().err
    assert refused.count("\n") == 1 and "--max-steps 1000" in refused and "--max-steps 30" in refused, refused
    assert main([*argv, "--allow-transfer"]) == 0
    with pytest.raises(UserError, match="give task$"):  # a ticket made by hand names no task
        goldenticket.evaluate("mine:make_policy", None, [], range(1_000_000, 1_000_010))


@pytest.mark.slow
def test_options_are_checked_before_any_episode_or_store_write(tmp_path, capsys):
    out = tmp_path / "run"
    search = ["search", "--policy", "metaworld/reach-v3/flow", "--task", "metaworld/reach-v3",
              "--out", str(out)]
    assert main([*search, "--validation-seeds", "1000001"]) == 2
    err = capsys.readouterr().err
    assert "validation" in err and err.count("\n") == 1 and not out.exists()
    assert main([*search, "--workers", "1000"]) == 2
    assert "--workers" in capsys.readouterr().err and not out.exists()


@pytest.mark.slow
def test_the_api_names_unknown_options_and_takes_several_tasks(tmp_path):
    with pytest.raises(UserError, match="unknown option unknown_option"):
        goldenticket.search("metaworld/mt10/flow", "metaworld/reach-v3", tmp_path / "x", unknown_option=1)
    with pytest.raises(UserError, match="unknown option budget"):
        goldenticket.evaluate("metaworld/mt10/flow", "metaworld/reach-v3", budget=1)
    summary = goldenticket.search("metaworld/mt10/flow", ("metaworld/reach-v3", "metaworld/push-v3"),
                                  tmp_path / "mt", budget=20, search_seeds=2, heldout=4, top_k=1, workers=1,
                                  method="rs")
    assert set(summary.verdict.tasks) == {"metaworld/reach-v3", "metaworld/push-v3"}


@pytest.mark.slow
def test_multi_task_search_checks_every_tasks_seeding(tmp_path):
    sys.path.insert(0, str(Path(__file__).parent))
    with pytest.raises(UserError, match="does not fix the initial state"):
        goldenticket.search("byo_example:make_policy", ("byo_example:make_env",
                                                        "byo_example:make_unseeded_env"),
                            tmp_path / "mt", budget=20, search_seeds=2, heldout=4, workers=1)
    assert not (tmp_path / "mt").exists()

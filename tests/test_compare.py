"""`goldenticket compare` and `goldenticket.compare`: two policies, or one with and without a ticket, on
the same held-out seeds; each arm's Wilson interval and the exact paired tests between them."""

import json
from dataclasses import fields

import numpy as np
import pytest
from scipy.stats import binomtest

import goldenticket
from goldenticket.cli import _parser, main
from goldenticket.config import CompareConfig
from goldenticket.errors import OptionError, flag
from goldenticket.evaluation import BASE, MIXTURE, ZERO, Arm, Judged, Kind
from goldenticket.policies import identity, load_policy
from goldenticket.report import comparison_text
from goldenticket.results import ComparedArm, Comparison
from goldenticket.rollout import NONFINITE, Engine, EpisodeResult
from goldenticket.stats import paired_exact_test
from goldenticket.tickets import Ticket, TicketRecord

FLOW, DDIM2, TASK = "metaworld/reach-v3/flow", "metaworld/reach-v3/ddim@2", "metaworld/reach-v3"
SEEDS, MAX_STEPS = range(1_000_000, 1_000_008), 40
FLAGS = ["--seeds", f"{SEEDS.start}:{SEEDS.stop}", "--max-steps", str(MAX_STEPS), "--workers", "1"]


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    """The bundled flow policy against its DDIM sibling at 2 steps, on reach-v3 (the task they were
    trained on, by default), every episode kept in the run store `out`."""
    out = tmp_path_factory.mktemp("compare")
    return goldenticket.compare(FLOW, DDIM2, seeds=SEEDS, max_steps=MAX_STEPS, workers=1, out=out), out


@pytest.fixture
def episodes_run(monkeypatch) -> list[int]:
    """The number of episodes each engine call runs."""
    calls, evaluate = [], Engine.evaluate

    def counted(self, episodes, *args, **kwargs):
        calls.append(len(episodes))
        return evaluate(self, episodes, *args, **kwargs)

    monkeypatch.setattr(Engine, "evaluate", counted)
    return calls


def _arm(policy: str, successes: str, nonfinite: int = 0) -> ComparedArm:
    results = tuple(EpisodeResult(1_000_000 + i, s == "1", float(s == "1"), 5, 0.0, cause=NONFINITE
                                  if i < nonfinite else None) for i, s in enumerate(successes))
    return ComparedArm(policy, None, BASE, Judged(results))


def _one_line(err: str) -> str:
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


@pytest.mark.slow
def test_two_bundled_policies_run_on_the_same_seeds_of_their_task(compared):
    comparison, _ = compared
    a, b = comparison.a, comparison.b
    assert comparison.task == TASK and comparison.seeds == (SEEDS.start, SEEDS.stop - 1)
    assert (a.policy, a.ticket, a.arm) == (FLOW, None, BASE)
    assert (b.policy, b.ticket, b.arm) == (DDIM2, None, Arm.other(DDIM2))
    assert a.rate.n == b.rate.n == len(a.successes) == len(b.successes) == len(SEEDS)
    assert a.successes != b.successes  # the two policies differ on these seeds
    base = goldenticket.evaluate(FLOW, TASK, seeds=SEEDS, max_steps=MAX_STEPS, workers=1)["base"]
    assert a.successes == base.successes and a.rate == base.rate  # A is the base `evaluate` judges


@pytest.mark.slow
def test_the_p_values_are_the_exact_paired_tests_on_each_seeds_successes(compared):
    comparison, _ = compared
    a, b = comparison.a.successes, comparison.b.successes
    assert comparison.p_a_better == paired_exact_test(a, b)
    assert comparison.p_b_better == paired_exact_test(b, a)
    assert comparison.a_only == sum(x and not y for x, y in zip(a, b, strict=True))
    assert comparison.b_only == sum(y and not x for x, y in zip(a, b, strict=True))
    discordant = comparison.a_only + comparison.b_only
    assert comparison.p_two_sided == pytest.approx(binomtest(comparison.a_only, discordant, 0.5).pvalue)


@pytest.mark.parametrize(("a", "b", "better"), [("1111111111", "0000000000", "A"),
                                                 ("0000000001", "1111111111", "B"),
                                                 ("1111100000", "0000011111", None)])
def test_the_verdict_is_the_two_sided_test_and_says_which_arm(a, b, better):
    comparison = Comparison(TASK, (1_000_000, 1_000_009), _arm(FLOW, a), _arm(DDIM2, b))
    assert comparison.better == better
    assert (comparison.p_two_sided < 0.05) == (better is not None)
    text = comparison_text(comparison)
    verdict = {"A": "A is better than B on these seeds", "B": "B is better than A on these seeds",
               None: "No significant difference between A and B on these seeds"}[better]
    assert verdict in text and f"two-sided p = {comparison.p_two_sided:.3g}" in text
    assert "exact McNemar (sign) test on the paired seeds" in text and "non-finite" not in text


def test_non_finite_episodes_get_a_column_where_any_ended_so():
    comparison = Comparison(TASK, (1_000_000, 1_000_003), _arm(FLOW, "0011", nonfinite=2),
                            _arm(DDIM2, "0111"))
    assert comparison.a.nonfinite == 2 and comparison.to_dict()["a"]["nonfinite_episodes"] == 2
    header, row_a = comparison_text(comparison).splitlines()[:2]
    assert header.split()[-1] == "non-finite" and row_a.split()[-1] == "2"


@pytest.mark.slow
def test_the_cli_table_resumes_from_the_run_store(compared, capsys, episodes_run, tmp_path):
    comparison, out = compared
    plot = tmp_path / "compare.png"
    assert main(["compare", "--policy", FLOW, "--against", DDIM2, *FLAGS, "--out", str(out),
                 "--plot", str(plot)]) == 0
    assert set(episodes_run) == {0}  # every episode read back
    text = capsys.readouterr().out
    assert f"A    {FLOW}" in text and f"B    {DDIM2}" in text
    assert f"discordant seeds: {comparison.a_only + comparison.b_only} of {len(SEEDS)}" in text
    assert f"p A > B = {comparison.p_a_better:.3g}, p B > A = {comparison.p_b_better:.3g}" in text
    assert "exact McNemar (sign) test" in text and plot.read_bytes().startswith(b"\x89PNG")


@pytest.mark.slow
def test_the_json_is_the_apis_comparison(compared, capsys, episodes_run):
    comparison, out = compared
    assert main(["compare", "--policy", FLOW, "--against", DDIM2, *FLAGS, "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads(json.dumps(comparison.to_dict())) and set(episodes_run) == {0}
    assert printed["a"]["arm"] == "base" and printed["b"]["arm"] == f"policy:{DDIM2}"
    assert {"p_a_better", "p_b_better", "p_two_sided", "better", "discordant", "test"} <= printed.keys()


@pytest.mark.slow
def test_a_run_store_of_another_comparison_is_refused(compared, capsys):
    _, out = compared
    other_noise = ["--seed", "1", "--out", str(out)]
    assert main(["compare", "--policy", FLOW, "--against", DDIM2, *FLAGS, *other_noise]) == 2
    assert "holds a different run" in _one_line(capsys.readouterr().err)


@pytest.mark.slow
def test_a_policy_against_itself_with_a_ticket(compared, tmp_path):
    policy = load_policy(FLOW)
    noise = np.random.default_rng(0).standard_normal(policy.noise_shape).astype(np.float32)
    record = TicketRecord(policy=FLOW, policy_fingerprint=identity(policy), noise_shape=policy.noise_shape,
                          task=TASK, max_steps=MAX_STEPS)
    ticket = Ticket(noise, record)
    path = ticket.save(tmp_path / "t.safetensors")
    comparison = goldenticket.compare(FLOW, FLOW, seeds=SEEDS, ticket=str(path), workers=1)
    a, b = comparison.a, comparison.b
    assert (a.policy, a.ticket, a.arm) == (FLOW, ticket.id, Arm.ticket(ticket.id))
    assert (b.policy, b.ticket, b.arm) == (FLOW, None, BASE)
    assert b.successes == compared[0].a.successes  # the base, under the ticket's own max_steps
    assert comparison.p_a_better == paired_exact_test(a.successes, b.successes)


def test_a_policy_that_does_not_fit_the_task_is_one_line(capsys):
    code = main(["compare", "--policy", FLOW, "--against", "robomimic/lift/flow", "--task", TASK, *FLAGS])
    assert code == 2
    assert "'robomimic/lift/flow'" in _one_line(capsys.readouterr().err)


def test_policies_trained_on_different_tasks_need_a_task(capsys):
    assert main(["compare", "--policy", FLOW, "--against", "metaworld/push-v3/flow", *FLAGS]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "metaworld/push-v3" in err and "--task" in err


def test_a_policy_against_itself_with_the_same_noise_is_refused(capsys):
    assert main(["compare", "--policy", FLOW, "--against", FLOW, *FLAGS]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "give --ticket or --against-ticket, or another policy as --against" in err
    with pytest.raises(OptionError, match="give ticket or against_ticket, or another policy as against$"):
        goldenticket.compare(FLOW, FLOW, seeds=SEEDS)


def test_every_option_of_compare_is_a_flag():
    sub = next(a for a in _parser()._actions if a.dest == "command").choices["compare"]
    flags = {s for a in sub._actions for s in a.option_strings}
    own = {"-h", "--help", "--config", "--out", "--plot", "--json"}
    assert flags - own == {flag(f.name) for f in fields(CompareConfig)}


def test_another_policys_arm_is_spelled_apart_from_the_others():
    assert [arm.key for arm in (BASE, ZERO, MIXTURE, Arm.ticket("ac7033f127b8"))] == [
        "base", "zero", "mixture", "ac7033f127b8"]
    other, ticketed = Arm.other(DDIM2), Arm.other("pkg.mod:factory", "ac7033f127b8")
    assert (other.kind, other.key, other.label) == (Kind.POLICY, f"policy:{DDIM2}", f"policy {DDIM2}")
    assert ticketed.key == "ac7033f127b8@policy:pkg.mod:factory"
    for arm in (BASE, ZERO, MIXTURE, Arm.ticket("ac7033f127b8"), other, ticketed):
        assert Arm.of(arm.key) == arm
    assert not other.candidate
    for bad in (lambda: Arm.ticket("a:b"), lambda: Arm(Kind.POLICY), lambda: Arm(Kind.BASE, policy=FLOW)):
        with pytest.raises(ValueError):
            bad()

"""Non-finite actions: failures of the arm that caused them, and a stop only when both the base and
the zero ticket break the policy on the same held-out seeds."""

import sys
from pathlib import Path

import numpy as np
import pytest

import goldenticket
from goldenticket.errors import UserError
from goldenticket.evaluation import BASE, ZERO, Arm, Evaluator, judge
from goldenticket.noise import Constant, Gaussian
from goldenticket.report import verdict_table
from goldenticket.rollout import NONFINITE, Engine
from goldenticket.tasks import get_task, seeds_in

sys.path.insert(0, str(Path(__file__).parent))  # byo_example
from byo_example import BiasedController, make_env  # noqa: E402

SEEDS = seeds_in("heldout", 30)
TASK = get_task("byo_example:make_env", max_steps=10)
ZEROS = Constant(np.zeros((4, 2), np.float32))


class NoiseBreaks(BiasedController):
    """NaN actions for noise whose first entry is above 2.5 where the goal lies right of x = -0.4
    (70% of the goals), and with `wild`, for noise with any entry beyond 2.5 (fresh Gaussian noise
    now and then)."""

    name = "noise-breaks"

    def __init__(self, wild: bool = False):
        self.wild = wild

    def act(self, obs, noise):
        actions = super().act(obs, noise)
        wild = self.wild & (np.abs(noise).max(axis=(1, 2)) > 2.5)
        actions[wild | ((noise[:, 0, 0] > 2.5) & (obs["goal"][:, 0] > -0.4))] = np.nan
        return actions


def _judged(policy, sources: dict):
    with Engine(policy, TASK, shard_size=8) as engine:
        return judge(Evaluator(engine), sources, SEEDS, Gaussian(0))


def test_a_base_often_non_finite_gets_a_verdict_counting_its_non_finite_episodes_as_failures():
    """The base is the user's policy as it is: its non-finite episodes are failures in its row."""
    rows = goldenticket.evaluate(NoiseBreaks(wild=True), make_env, seeds=SEEDS, max_steps=10, workers=1)
    base = rows["base"]
    assert base.nonfinite > 0.1 * len(SEEDS) and rows["zero"].nonfinite == 0
    assert base.rate.successes <= len(SEEDS) - base.nonfinite
    table = verdict_table({label: row.to_dict() for label, row in rows.items()})
    header, base_line = table.splitlines()[:2]
    assert "non-finite" in header and f" {base.nonfinite} " in base_line


def test_a_ticket_that_breaks_the_policy_is_judged_failing_and_the_run_goes_on():
    breaking = np.zeros((4, 2), np.float32)
    breaking[0, 0] = 3
    verdict = _judged(NoiseBreaks(), {ZERO: ZEROS, Arm.ticket("breaking"): Constant(breaking)})
    ticket, rows = verdict.arms[Arm.ticket("breaking")], verdict.rows
    assert ticket.nonfinite > 0.5 * len(SEEDS) and rows[BASE].nonfinite <= 0.1 * len(SEEDS)
    assert all(not r.success for r in ticket.results if r.cause == NONFINITE)
    assert not rows[Arm.ticket("breaking")].golden and rows[ZERO].nonfinite == 0


def test_a_ticket_run_alone_never_stops_on_non_finite_actions():
    with Engine("byo_example:make_nan_policy", TASK, shard_size=8) as engine:
        results = Evaluator(engine).run([("some-ticket", ZEROS, SEEDS)])[0]
    assert all(r.cause == NONFINITE for r in results)


def test_base_and_zero_both_over_the_limit_stop_the_run_naming_both_arms():
    says = (r"NaN or infinite actions in \d+ of the 30 held-out episodes of base and \d+ of zero, more "
            r"than max_nonfinite 0\.1 of them in each \(the first on seed 1000000, at step 0, under base\): "
            r".*policy or its adapter is broken")
    ticket = Constant(np.ones((4, 2), np.float32))
    with pytest.raises(UserError, match=says):
        _judged("byo_example:make_nan_policy", {ZERO: ZEROS, Arm.ticket("ticket"): ticket})


@pytest.mark.slow
def test_a_search_whose_judged_ticket_breaks_the_policy_delivers_a_verdict(tmp_path):
    """A candidate that drives the policy to NaN on most held-out seeds is judged failing and passed
    over: the search still ends in its verdict."""
    from goldenticket.tickets import Ticket

    breaking = np.zeros((4, 2), np.float32)
    breaking[0, 0] = 3.0
    given = Ticket(breaking).save(tmp_path / "breaking.safetensors")
    summary = goldenticket.search(NoiseBreaks(), make_env, tmp_path / "run", method="rs", budget=8,
                                  search_seeds=2, heldout=30, top_k=10, validation_seeds=4,
                                  tickets=[str(given)], max_steps=10, workers=1)
    judged = {t.source: t for t in summary.tickets}
    broken = judged[f"given: {given}"].heldout
    assert broken.nonfinite > 0.5 * 30 and not broken.golden
    assert summary.best.source != f"given: {given}" and summary.base.nonfinite <= 0.1 * 30

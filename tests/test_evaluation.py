import sys
from pathlib import Path

import numpy as np
import pytest

from goldenticket.errors import UserError
from goldenticket.evaluation import BASE, ZERO, Bar, Evaluator, judge
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import NONFINITE, Engine
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in

POLICY, TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"
sys.path.insert(0, str(Path(__file__).parent))  # byo_example


class CountingEngine(Engine):
    def evaluate(self, episodes, on_shard=None, task=None):
        self.asked = getattr(self, "asked", 0) + len(episodes)
        return super().evaluate(episodes, on_shard, task)


def test_resume_reads_finished_episodes_back_instead_of_rerunning(tmp_path):
    seeds, zero = seeds_in("heldout", 4), Constant(np.zeros((8, 4), np.float32))
    with CountingEngine(POLICY, get_task(TASK, max_steps=60), shard_size=3) as engine:
        first = Evaluator(engine, RunStore(tmp_path / "run.sqlite")).run([("base", Gaussian(), seeds)])
        resumed = Evaluator(engine, RunStore(tmp_path / "run.sqlite"))
        both = resumed.run([("base", Gaussian(), seeds), ("zero", zero, seeds)])
    assert engine.asked == 8  # 4 base episodes, then only the 4 new zero-ticket ones
    assert both[0] == first[0]
    rows = RunStore(tmp_path / "run.sqlite").episodes(seed_set="heldout")
    assert len(rows) == 8 and {r.ticket_id for r in rows} == {"base", "zero"}


def test_judge_pairs_every_source_with_the_base_on_the_same_seeds():
    seeds = seeds_in("heldout", 6)
    with Engine(POLICY, get_task(TASK)) as engine:
        rows = judge(Evaluator(engine), {ZERO: Constant(np.zeros((8, 4), np.float32))}, seeds).rows
    assert rows[BASE].p_vs_base is None and rows[BASE].rate.n == 6
    assert 0 <= rows[ZERO].p_vs_base <= 1 and rows[ZERO].rate.n == 6


def test_an_episode_that_begins_elsewhere_than_the_first_on_its_seed_stops_the_run_unrecorded(tmp_path):
    """An env whose reset ignores the seed: each seed's first episode records its initial state
    (in the store), and a later episode on that seed, in this run or a resumed one, stops it."""
    seeds, task = seeds_in("heldout", 2), get_task("byo_example:make_unseeded_env", max_steps=5)
    zero = Constant(np.zeros((4, 2), np.float32))
    with Engine("byo_example:make_policy", task, shard_size=2) as engine:
        Evaluator(engine, RunStore(tmp_path / "run.sqlite")).run([("base", Gaussian(), seeds)])
        resumed = Evaluator(engine, RunStore(tmp_path / "run.sqlite"))
        with pytest.raises(UserError, match=r"reset\(seed=1000000\) does not fix the initial state from one "
                                            "episode to the next"):
            resumed.run([("base", Gaussian(), seeds), ("zero", zero, seeds)])
        with pytest.raises(UserError, match="does not fix the initial state"):  # no store: in memory
            Evaluator(engine).run([("base", Gaussian(), seeds), ("base again", Gaussian(), seeds)])
    assert {r.ticket_id for r in RunStore(tmp_path / "run.sqlite").episodes()} == {"base"}


def test_a_policy_non_finite_on_too_many_heldout_episodes_stops_the_run_and_its_rerun(tmp_path):
    task, seeds = get_task("byo_example:make_env", max_steps=5), seeds_in("heldout", 40)
    with CountingEngine("byo_example:make_nan_policy", task, shard_size=8) as engine:
        with pytest.raises(UserError, match="NaN or infinite actions in 8 of the 40 held-out episodes of "
                                            "base, more than max_nonfinite 0.1 of them"):
            Evaluator(engine, RunStore(tmp_path / "run.sqlite")).run([("base", Gaussian(), seeds)])
        assert engine.asked == 40  # one engine call, stopped after its first shard
        rows = RunStore(tmp_path / "run.sqlite").episodes()
        assert len(rows) == 8 and {r.cause for r in rows} == {NONFINITE}
        with pytest.raises(UserError, match="in 8 of the 40"):  # the rerun stops before any episode runs
            Evaluator(engine, RunStore(tmp_path / "run.sqlite")).run([("base", Gaussian(), seeds)])
        assert engine.asked == 40
        lenient = Evaluator(engine, RunStore(tmp_path / "run.sqlite"), max_nonfinite=1)
        results = lenient.run([("base", Gaussian(), seeds)])[0]
        assert len(results) == 40 and all(r.cause == NONFINITE and not r.success for r in results)


def test_a_bar_that_a_signal_cut_off_in_its_constructor_closes_quietly(capfd):
    """Ctrl-C inside tqdm's __init__ leaves a bar with no position; collecting it must not print a
    traceback after the one-line stop message."""
    bar = Bar.__new__(Bar)
    bar.disable, bar.leave = False, True  # what __init__ had set before the signal
    bar.__del__()
    assert capfd.readouterr() == ("", "")

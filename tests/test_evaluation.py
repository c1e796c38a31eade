import numpy as np

from goldenticket.evaluation import Evaluator, judge
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import Engine
from goldenticket.store import RunStore
from goldenticket.tasks import get_task, seeds_in

POLICY, TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"


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
        judged = judge(Evaluator(engine), {"zero": Constant(np.zeros((8, 4), np.float32))}, seeds)
    assert judged["base"].p_value is None and judged["base"].rate.n == 6
    assert 0 <= judged["zero"].p_value <= 1 and judged["zero"].rate.n == 6

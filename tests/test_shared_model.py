"""Env workers acting through one policy in the main process (goldenticket.shared_model), as they do
on a GPU: the same results as workers that each load the policy, and its errors in one line."""

import sys
from pathlib import Path

import numpy as np
import pytest

from goldenticket.errors import UserError
from goldenticket.noise import Constant, Gaussian
from goldenticket.rollout import Engine, Episode
from goldenticket.shared_model import PolicyServer
from goldenticket.tasks import get_task, seeds_in

sys.path.insert(0, str(Path(__file__).parent))  # byo_example, here and in worker processes


@pytest.mark.slow
def test_workers_sharing_one_policy_give_the_results_of_workers_with_their_own():
    task = get_task("metaworld/pick-place-v3", max_steps=60)
    ticket = np.random.default_rng(0).standard_normal((8, 4)).astype(np.float32)
    seeds = seeds_in("heldout", 6)
    episodes = [Episode(source, s) for source in (Gaussian(), Constant(ticket)) for s in seeds]
    with Engine("metaworld/pick-place-v3/flow", task, workers=2, shard_size=4, share_model=True) as shared:
        assert shared._server is not None and shared.policy is not None
        together = shared.evaluate(episodes)
    with Engine("metaworld/pick-place-v3/flow", task, workers=2, shard_size=4) as own:
        assert own._server is None and own.policy is None
        apart = own.evaluate(episodes)
    assert [(r.success, r.ret, r.length) for r in together] == [(r.success, r.ret, r.length) for r in apart]


def test_on_the_cpu_workers_load_their_own_policy_unless_asked():
    with Engine("metaworld/pick-place-v3/flow", get_task("metaworld/pick-place-v3"), workers=2) as engine:
        assert engine._server is None


@pytest.mark.slow
def test_an_error_in_the_shared_policy_reaches_the_run_as_one_line():
    task = get_task("byo_example:make_env", max_steps=5)
    line = r"act\(\) failed at .*byo_example.py:\d+: KeyError: 'velocity'"
    with Engine("byo_example:make_raising_policy", task, workers=2, share_model=True) as engine, \
            pytest.raises(UserError, match=line) as error:
        engine.evaluate([Episode(Gaussian(), s) for s in seeds_in("heldout", 2)])
    assert len(str(error.value).splitlines()) == 1


def test_a_multi_task_policy_is_not_shared_unconditioned():
    class MultiTask:
        name, tasks, noise_shape, n_exec = "multi", ("a", "b"), (8, 4), 4

    with pytest.raises(UserError, match="conditioned on its tasks; workers cannot share it"):
        PolicyServer(MultiTask())

import numpy as np
import pytest

from goldenticket.noise import Constant, Gaussian, TopK
from goldenticket.policies import load_policy
from goldenticket.rollout import NONFINITE, Episode, rollout
from goldenticket.tasks import get_task, seeds_in
from goldenticket.tasks.base import observation_digest


@pytest.mark.slow
def test_results_do_not_depend_on_batch_slot():
    """The bundled (trained) policy, so episodes differ in length and outcome."""
    policy, task = load_policy("metaworld/pick-place-v3/flow"), get_task("metaworld/pick-place-v3")
    ticket = Constant(np.full(policy.noise_shape, 0.5, np.float32))
    seeds = seeds_in("search", 6)
    episodes = [Episode(Gaussian(1) if i % 2 else ticket, s) for i, s in enumerate(seeds)]
    together = rollout(policy, task, episodes)
    reversed_ = rollout(policy, task, episodes[::-1])[::-1]
    alone = [rollout(policy, task, [ep])[0] for ep in episodes]
    key = [(r.seed, r.success, r.ret, r.length) for r in together]
    assert len({r.length for r in together}) > 1  # not all identical failures
    assert key == [(r.seed, r.success, r.ret, r.length) for r in reversed_]
    assert key == [(r.seed, r.success, r.ret, r.length) for r in alone]


def test_noise_sources_are_reproducible_per_episode():
    shape = (8, 4)
    a, b = Gaussian(3).sampler(10, shape), Gaussian(3).sampler(10, shape)
    assert np.array_equal(a(), b()) and np.array_equal(a(), b())
    assert not np.array_equal(Gaussian(3).sampler(11, shape)(), Gaussian(3).sampler(10, shape)())
    tickets = np.stack([np.full(shape, i, np.float32) for i in range(3)])
    draws = [TopK(tickets, 0).sampler(5, shape)()[0, 0] for _ in range(2)]
    assert draws[0] == draws[1]


def test_only_objectives_that_read_progress_ask_the_env_for_it(monkeypatch):
    from goldenticket.tasks.metaworld import MetaWorldEnv

    policy, task = load_policy("metaworld/reach-v3/flow"), get_task("metaworld/reach-v3", max_steps=8)
    episodes = [Episode(Gaussian(0), s) for s in seeds_in("search", 2)]  # 8 steps: both fail
    graded = rollout(policy, task, episodes, objective="success-progress")
    assert all(not r.success and 0 < r.ret <= 0.01 for r in graded)

    def unwanted(self):
        raise AssertionError("progress() read for an objective that does not use it")

    monkeypatch.setattr(MetaWorldEnv, "progress", unwanted)
    assert [r.ret for r in rollout(policy, task, episodes)] == [0.0, 0.0]


class Poisoned:
    """The bundled policy, whose actions are NaN for one observation (one state of one episode);
    it keeps every observation it is called with."""

    def __init__(self, policy, poison: np.ndarray | None = None):
        self.policy, self.poison, self.seen = policy, poison, []
        self.noise_shape, self.n_exec, self.name = policy.noise_shape, policy.n_exec, "poisoned"

    def act(self, obs, noise):
        self.seen += list(obs)
        actions = self.policy.act(obs, noise)
        if self.poison is not None:
            actions[(obs == self.poison).all(axis=1)] = np.nan
        return actions


def test_a_nonfinite_action_ends_its_episode_as_a_failure_and_no_other():
    policy, task = load_policy("metaworld/reach-v3/flow"), get_task("metaworld/reach-v3", max_steps=40)
    episodes = [Episode(Gaussian(0), s) for s in seeds_in("heldout", 6)]
    clean = Poisoned(policy)
    before = rollout(clean, task, episodes, objective="speed", record_actions=True)
    poison = clean.seen[3 * len(episodes) + 2]  # the 4th call's third row: an episode's mid-way state
    after = rollout(Poisoned(policy, poison), task, episodes, objective="speed", record_actions=True)
    hit = [i for i, r in enumerate(after) if r.cause == NONFINITE]
    assert len(hit) == 1 and after[hit[0]].length == 3 * policy.n_exec < before[hit[0]].length
    assert not after[hit[0]].success and after[hit[0]].ret == 0.0
    assert np.array_equal(after[hit[0]].actions, before[hit[0]].actions[: after[hit[0]].length])
    for i, (a, b) in enumerate(zip(after, before, strict=True)):
        if i != hit[0]:  # bitwise the same episodes, executed actions included
            assert (a.success, a.ret, a.length, a.cause) == (b.success, b.ret, b.length, None)
            assert np.array_equal(a.actions, b.actions) and a.digest == b.digest


def test_the_initial_observation_digest_names_the_state():
    obs = get_task("metaworld/reach-v3").make_env().reset(1_000_000)
    assert observation_digest(obs) == observation_digest(obs.copy())
    assert observation_digest(obs) != observation_digest(np.nextafter(obs, np.inf))
    as_dict = {"b": obs[:3], "a": obs}
    assert observation_digest(as_dict) == observation_digest(dict(reversed(as_dict.items())))

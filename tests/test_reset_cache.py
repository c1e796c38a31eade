"""Meta-World resets restored from the process's reset cache give Meta-World's own episodes, to the bit."""

from collections import OrderedDict

import numpy as np
import pytest

from goldenticket.tasks import get_task
from goldenticket.tasks import metaworld as metaworld_module
from goldenticket.tasks import pixels as pixels_module
from goldenticket.tasks.base import observation_digest
from goldenticket.tasks.metaworld import MetaWorldEnv
from goldenticket.tasks.metaworld_fast import SUCCESS

# (env, seed, steps): two envs' episodes in turns, seeds repeated in other orders between others,
# each cut before its end
SCHEDULE = [(0, 11, 12), (1, 12, 9), (0, 12, 14), (1, 11, 6), (0, 13, 8), (1, 11, 12), (0, 11, 10),
            (1, 13, 7), (0, 12, 5)]


@pytest.fixture(autouse=True)
def empty_cache(monkeypatch):
    monkeypatch.setattr(metaworld_module, "_resets", OrderedDict())


def record(env, seed: int, actions: np.ndarray, between=lambda action: None) -> list:
    """An episode: its observations' digests (every byte), each step's success and done, then the state
    and progress() at its end; `between(action)` after each step."""
    out = [observation_digest(env.reset(seed))]
    for action in actions:
        observation, success, done = env.step(action)
        out.append((observation_digest(observation), success, done))
        between(action)
    return out + [(env.state.tobytes(), env.progress())]


@pytest.mark.parametrize("task", sorted(SUCCESS))
def test_cached_resets_give_the_same_episodes(task):
    """Two envs sharing the cache and stepped in turns, against an env that runs Meta-World's reset
    each time (beforehand: its resets would put the seed's object positions in the shared model)."""
    rng = np.random.default_rng(0)
    plan = [(which, seed, rng.uniform(-1, 1, (steps, 4))) for which, seed, steps in SCHEDULE]
    fresh = MetaWorldEnv(task, cache_resets=False)
    expected = [record(fresh, seed, actions) for _, seed, actions in plan]
    cached = [MetaWorldEnv(task), MetaWorldEnv(task)]
    for env in cached:
        env.reset(10)
    for (which, seed, actions), reference in zip(plan, expected, strict=True):
        # the other env steps in turns: the shared Meta-World env changes hands at every step
        assert record(cached[which], seed, actions, between=cached[1 - which].step) == reference
    assert sorted(metaworld_module._resets) == [(task, seed) for seed in (10, 11, 12, 13)]


def test_an_episode_cut_short_leaves_nothing_behind():
    """Pick-place keeps views of the simulation among its attributes (its initial pad positions, read
    by progress()): a restored reset is a copy, whatever the episodes before it did."""
    task = "pick-place-v3"
    ours, other, theirs = MetaWorldEnv(task), MetaWorldEnv(task), MetaWorldEnv(task, cache_resets=False)
    actions = np.random.default_rng(1).uniform(-1, 1, (40, 4))
    reference = record(theirs, 5, actions)
    assert record(ours, 5, actions[:25])[:26] == reference[:26]  # Meta-World's reset, the episode cut short
    assert record(ours, 5, actions) == reference  # restored
    assert record(other, 5, actions[:30])[:31] == reference[:31]
    assert record(ours, 5, actions) == reference  # after `other` was cut short too


def test_cached_resets_draw_the_same_frames():
    """The camera task's frames after restored resets, against frames after Meta-World's."""
    task = "drawer-open-v3"
    reference = pixels_module.PixelsEnv(task)
    reference._env = MetaWorldEnv(task, cache_resets=False)
    rng = np.random.default_rng(2)
    plan = [(seed, rng.uniform(-1, 1, (6, 4))) for seed in (3, 4, 3, 3, 4)]
    expected = [record(reference, seed, actions) for seed, actions in plan]
    env = get_task(f"metaworld-pixels/{task}").make_env()
    assert [record(env, seed, actions) for seed, actions in plan] == expected


def test_the_cache_keeps_the_most_recently_used(monkeypatch):
    monkeypatch.setattr(metaworld_module, "RESET_CACHE_SIZE", 2)
    task = "reach-v3"
    env, fresh = MetaWorldEnv(task), MetaWorldEnv(task, cache_resets=False)
    for seed in (1, 2, 1, 3):
        env.reset(seed)
    assert list(metaworld_module._resets) == [(task, 1), (task, 3)]  # 2: used least recently
    assert env.reset(2).tobytes() == fresh.reset(2).tobytes()  # Meta-World's reset again
    assert list(metaworld_module._resets) == [(task, 3), (task, 2)]
    MetaWorldEnv(task, fast=False).reset(4)
    assert list(metaworld_module._resets) == [(task, 3), (task, 2)]  # the stock env keeps nothing

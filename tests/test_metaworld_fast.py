"""The fast Meta-World path computes the same floats as Meta-World's own Python, step by step."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from goldenticket.policies import load_policy
from goldenticket.tasks import seeds_in
from goldenticket.tasks.metaworld import MetaWorldEnv, task_names
from goldenticket.tasks.metaworld_fast import SUCCESS, quaternion

pytestmark = pytest.mark.slow


def test_quaternion_is_scipys_to_the_bit():
    half_turns = [np.diag(d) for d in ([1, -1, -1], [-1, 1, -1], [-1, -1, 1], [1, 1, 1])]
    small = Rotation.from_rotvec(np.random.default_rng(1).normal(0, 1e-3, (2000, 3))).as_matrix()
    rotations = Rotation.random(20000, rng=np.random.default_rng(0)).as_matrix()
    matrices = np.stack([*half_turns, *small, *rotations])
    for matrix, expected in zip(matrices, Rotation.from_matrix(matrices).as_quat(), strict=True):
        assert np.array_equal(quaternion(matrix), expected)


ACTIONS = np.random.default_rng(5).uniform(-1, 1, (25, 4))


def _steps(env: MetaWorldEnv, seed: int, actions) -> tuple[np.ndarray, list]:
    """The observation after reset(seed), and (observation, success) after each action, or until
    the episode ends."""
    first, out = env.reset(seed), []
    for action in actions:
        obs, success, done = env.step(action)
        out.append((obs, success))
        if done:
            break
    return first, out


@pytest.mark.parametrize("task", [t.split("/")[1] for t in task_names()])
def test_every_task_observes_as_stock(task):
    """Two fast envs sharing one model, stepped in turns, each against its own stock env."""
    fast = [MetaWorldEnv(task) for _ in range(2)]
    firsts, stock = zip(*(_steps(MetaWorldEnv(task, fast=False), seed, ACTIONS) for seed in (7, 8)),
                        strict=True)
    for env, seed in zip(fast, (7, 8), strict=True):
        env.reset(seed + 1)  # another history first
    for env, seed, first in zip(fast, (7, 8), firsts, strict=True):
        assert np.array_equal(env.reset(seed), first)  # a new stock env's
    for step, action in enumerate(ACTIONS):
        for env, reference in zip(fast, stock, strict=True):
            if step < len(reference):
                obs, success, _ = env.step(action)
                assert np.array_equal(obs, reference[step][0]) and success == reference[step][1]


@pytest.mark.parametrize("task", sorted(SUCCESS))
def test_bundled_policy_episodes_are_stocks_to_the_bit(task):
    """Policy-driven episodes, so that successes and contacts happen; each step compared."""
    policy = load_policy(f"metaworld/{task}/flow")
    fast, stock = MetaWorldEnv(task), MetaWorldEnv(task, fast=False)
    successes = 0
    for seed in seeds_in("search", 3):
        rng, obs = np.random.default_rng(seed), fast.reset(seed)
        assert np.array_equal(obs, stock.reset(seed))
        for _ in range(150 // policy.n_exec):
            noise = rng.standard_normal((1, *policy.noise_shape)).astype(np.float32)
            for action in policy.act(obs[None], noise)[0]:
                obs, success, _ = fast.step(action)
                stock_obs, stock_success, _ = stock.step(action)
                assert np.array_equal(obs, stock_obs) and success == stock_success
                if task in ("pick-place-v3", "push-v3"):
                    ours, theirs = fast._host.lend(fast), stock._host.lend(stock)
                    geom = ours._get_id_main_object()
                    assert ours.touching_object(geom) == theirs.touching_object(geom)
            if success:
                successes += 1
                break
    assert successes > 0, "the comparison never reached a success"

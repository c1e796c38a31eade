"""robomimic's tasks on robosuite 1.5.2 (goldenticket.tasks.robomimic). Marked `robomimic`: they run in
the venv with the `robomimic` extra (README, "robomimic") and are skipped without it."""

import importlib.metadata
import importlib.util
import time

import numpy as np
import pytest

from goldenticket.tasks import get_task
from goldenticket.tasks.base import observation_digest


def robosuite_version() -> str | None:
    return importlib.metadata.version("robosuite") if importlib.util.find_spec("robosuite") else None


pytestmark = [pytest.mark.robomimic, pytest.mark.skipif(
    robosuite_version() != "1.5.2", reason="robosuite 1.5.2 is not installed (its own venv: README)")]
NAMES = ("robomimic/lift", "robomimic/can", "robomimic/square", "robomimic/transport")


@pytest.mark.parametrize("name", NAMES)
def test_observations_are_robomimics_low_dim_keys_in_dppos_order(name):
    task = get_task(name)
    env = task.make_env()
    obs = env.reset(1_000_000)
    assert obs.shape == (task.obs_dim,) and obs.dtype == np.float64
    next_obs, success, done = env.step(np.zeros(task.action_dim))
    assert next_obs.shape == obs.shape and not success and not done


@pytest.mark.slow
@pytest.mark.parametrize("name", ["robomimic/lift", "robomimic/can"])
def test_every_seed_is_one_initial_state_in_any_env_and_process(name):
    task = get_task(name)
    task.check()
    env = task.make_env()
    assert observation_digest(env.reset(3)) != observation_digest(env.reset(4))


def test_a_reset_is_fast_and_episodes_end_at_robomimics_horizon():
    task = get_task("robomimic/can")
    env = task.make_env()
    start = time.perf_counter()
    for seed in range(5):
        env.reset(seed)
    assert (time.perf_counter() - start) / 5 < 0.2  # no scene rebuilt
    assert task.max_steps == 400 and get_task("robomimic/transport").max_steps == 700


def test_a_lifted_cube_is_a_success():
    """Lift's own success test: the cube above the table by 4 cm."""
    env = get_task("robomimic/lift").make_env()
    env.reset(0)
    sim = env._env.sim
    cube = env._env.cube_body_id
    joint = env._env.cube.joints[0]
    qpos = sim.data.get_joint_qpos(joint).copy()
    qpos[2] += 0.1
    sim.data.set_joint_qpos(joint, qpos)
    sim.forward()
    assert sim.data.body_xpos[cube][2] > env._env.model.mujoco_arena.table_offset[2] + 0.04
    assert env.step(np.zeros(7))[1]

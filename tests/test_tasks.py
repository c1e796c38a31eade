import importlib.util
import multiprocessing as mp

import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.seeds import seed_set_of
from goldenticket.tasks import SEED_SETS, get_task, seeds_in

TASK = "metaworld/pick-place-v3"


def _first_obs_and_episode(seed: int) -> tuple[np.ndarray, np.ndarray]:
    env = get_task(TASK).make_env()
    env.reset(seed + 1)  # a different history first: it must not leak into the next reset
    for _ in range(5):
        env.step(np.ones(4))
    first = env.reset(seed)
    actions = np.random.default_rng(7).uniform(-1, 1, (20, 4))
    trajectory = np.stack([env.step(a)[0] for a in actions])
    return first, trajectory


def test_same_seed_same_initial_state_and_episode_in_two_envs():
    a_first, a_traj = _first_obs_and_episode(3)
    env = get_task(TASK).make_env()  # fresh env, no history
    b_first = env.reset(3)
    assert np.array_equal(a_first, b_first)
    assert np.array_equal(a_first, _first_obs_and_episode(3)[0])
    assert np.array_equal(a_traj, _first_obs_and_episode(3)[1])


def test_different_seeds_give_different_initial_states():
    env = get_task(TASK).make_env()
    firsts = {env.reset(s)[4:7].tobytes() for s in range(5)}  # object position
    assert len(firsts) == 5


def test_same_seed_same_episode_in_two_processes():
    here = _first_obs_and_episode(11)
    with mp.get_context("spawn").Pool(1) as pool:
        there = pool.apply(_first_obs_and_episode, (11,))
    assert np.array_equal(here[0], there[0]) and np.array_equal(here[1], there[1])


def test_seed_sets_are_disjoint():
    blocks = list(SEED_SETS.values())
    for i, a in enumerate(blocks):
        for b in blocks[i + 1:]:
            assert a.stop <= b.start or b.stop <= a.start
    assert seed_set_of(seeds_in("heldout", 1)[0]) == "heldout"


def test_bad_task_and_seed_requests_are_user_errors():
    with pytest.raises(UserError, match="unknown task"):
        get_task("metaworld/no-such-task")
    with pytest.raises(UserError):
        seeds_in("search", 2_000_000)


@pytest.mark.parametrize(("name", "says"), [
    ("libero/kitchen/0", "unknown LIBERO suite in 'libero/kitchen/0'; the suites are spatial, object"),
    ("libero-listed/object/10", "LIBERO-object has task ids 0 to 9, not '10'"),
    ("libero/object", "unknown LIBERO suite"),
])
def test_unknown_libero_suites_and_task_ids_are_one_line(capsys, name, says):
    assert main(["evaluate", "--policy", "metaworld/reach-v3/flow", "--task", name,
                 "--seeds", "1000000:1000002"]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1


@pytest.mark.skipif(importlib.util.find_spec("lerobot") is not None, reason="LeRobot is installed here")
def test_lerobot_envs_without_lerobot_say_how_to_install_it():
    says = "LeRobot's envs need the package 'lerobot': install goldenticket's \"lerobot\" extra"
    with pytest.raises(UserError, match=says):
        get_task("pusht")


def test_unknown_robomimic_tasks_are_one_line():
    with pytest.raises(UserError, match="unknown robomimic task 'robomimic/stack'; they are robomimic/lift"):
        get_task("robomimic/stack")


@pytest.mark.skipif(importlib.util.find_spec("robosuite") is not None, reason="robosuite is installed here")
def test_robomimic_tasks_without_robosuite_say_how_to_install_it():
    with pytest.raises(UserError, match=r"tasks need robosuite 1.5.2: pip install -e \"\.\[robomimic\]"):
        get_task("robomimic/can").make_env()


def test_objectives_rank_episodes_as_documented():
    from goldenticket.tasks import OBJECTIVES


    success, discounted, length, tie_broken = (
        OBJECTIVES[k] for k in ("success", "discounted-success", "length", "success-progress"))
    assert success(True, 80, 150, 1.0) == 1.0 and success(False, 150, 150, 0.7) == 0.0
    assert 1.0 > discounted(True, 40, 150, 1) > discounted(True, 80, 150, 1) > discounted(False, 30, 150, 0)
    assert length(True, 40, 150, 1) > length(True, 80, 150, 1) > length(False, 150, 150, 0) == -1.0
    # progress breaks ties between failures, but 100 episodes' progress never outweighs one success
    assert tie_broken(False, 150, 150, 0.6) > tie_broken(False, 150, 150, 0.2)
    assert tie_broken(True, 90, 150, 1.0) * 1 + 99 * tie_broken(False, 150, 150, 0.0) > \
        100 * tie_broken(False, 150, 150, 0.99)


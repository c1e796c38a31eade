"""LeRobot's VLAs as policies (goldenticket.policies.lerobot.vla): SmolVLAs built offline with random
weights on a tiny backbone, and the shipped one, against LeRobot's own eval loop. Marked `lerobot`:
they run in LeRobot's venv (README, "LeRobot") and are skipped without it."""

import importlib.util
import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.noise import Constant
from goldenticket.policies import load_policy
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT))  # examples.*, here and in worker processes
sys.path.insert(0, str(Path(__file__).parent))
from lerobot_checks import CameraReach, robot_loop_acts_as_goldenticket, same_actions_as_lerobot  # noqa: E402
from lerobot_models import save, tiny_smolvla  # noqa: E402

pytestmark = [pytest.mark.lerobot, pytest.mark.slow, pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None, reason="LeRobot is not installed (its own venv: README)")]
INSTRUCTION = CameraReach.task_description
SIZE = 32  # camera frames, height and width


class TwoCameras(CameraReach):
    size, cameras = SIZE, ("image", "image1")


class OneCamera(TwoCameras):
    cameras = ("image",)


class OtherCamera(TwoCameras):
    cameras = ("image", "wrist")


class Unsaid(TwoCameras):
    task_description = None


def two_cameras() -> gym.Env:
    return gym.wrappers.TimeLimit(TwoCameras(), 12)


def one_camera() -> gym.Env:
    return gym.wrappers.TimeLimit(OneCamera(), 12)


def other_camera() -> gym.Env:
    return gym.wrappers.TimeLimit(OtherCamera(), 12)


def no_instruction() -> gym.Env:
    return gym.wrappers.TimeLimit(Unsaid(), 12)


@pytest.fixture(scope="module")
def backbone(tmp_path_factory) -> Path:
    from examples.smolvla_backbone import write_backbone

    return write_backbone(tmp_path_factory.mktemp("backbone"), "tiny")


def features(cameras: int):
    from lerobot.configs.types import FeatureType, PolicyFeature

    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (4,)),
              "observation.environment_state": PolicyFeature(FeatureType.ENV, (6,))}
    inputs |= {f"observation.images.image{i or ''}": PolicyFeature(FeatureType.VISUAL, (3, SIZE, SIZE))
               for i in range(cameras)}
    return inputs, {"action": PolicyFeature(FeatureType.ACTION, (4,))}


def smolvla(folder: Path, backbone: Path, cameras: int = 2, **settings) -> Path:
    """An untrained SmolVLA on the tiny offline backbone, reading `cameras` cameras."""
    inputs, outputs = features(cameras)
    return tiny_smolvla(folder, backbone, settings.pop("input_features", inputs), outputs, **settings)


def small_vision(paligemma):
    """PaliGemma's builder with a one-layer SigLIP projecting to the VLM's width (LeRobot pins 2048)."""
    def build(config):
        width = config.text_config.hidden_size
        config.vision_config.update({"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 1,
                                     "num_attention_heads": 1, "projection_dim": width})
        return paligemma(config=config)
    return build


@pytest.fixture
def tiny_paligemma(monkeypatch, backbone):
    """pi0 and pi0.5 at test size. LeRobot fixes their VLM and action expert to Gemma variants of 2B and
    300M parameters and their tokenizer to PaliGemma's hub name; here both variants are one-layer Gemmas,
    the vision tower is one SigLIP layer and the tokenizer is the tiny backbone's. The rest, the flow
    matching, prefix, attention masks and processors, is LeRobot's own code."""
    from lerobot.policies.pi0 import modeling_pi0, processor_pi0
    from lerobot.policies.pi05 import modeling_pi05, processor_pi05
    from lerobot.processor import TokenizerProcessorStep

    gemma = modeling_pi0.GemmaConfig
    sizes = {"gemma_2b": gemma(width=64, depth=1, mlp_dim=64, num_heads=1, num_kv_heads=1, head_dim=16),
             "gemma_300m": gemma(width=32, depth=1, mlp_dim=32, num_heads=1, num_kv_heads=1, head_dim=16)}
    for modeling in (modeling_pi0, modeling_pi05):
        monkeypatch.setattr(modeling, "get_gemma_config", sizes.__getitem__)
        monkeypatch.setattr(modeling, "PaliGemmaForConditionalGenerationWithPiGemma",
                            small_vision(modeling.PaliGemmaForConditionalGenerationWithPiGemma))
    for processor in (processor_pi0, processor_pi05):
        monkeypatch.setattr(processor, "TokenizerProcessorStep",
                            lambda **kw: TokenizerProcessorStep(**kw | {"tokenizer_name": str(backbone)}))


def paligemma_vla(kind: str, folder: Path, cameras: int = 2) -> Path:
    """An untrained pi0 or pi0.5 ("pi05"), of tiny_paligemma's sizes."""
    import torch
    from lerobot.policies.factory import get_policy_class, make_policy_config

    inputs, outputs = features(cameras)
    cfg = make_policy_config(kind, input_features=inputs, output_features=outputs, device="cpu",
                             push_to_hub=False, chunk_size=10, n_action_steps=5, num_inference_steps=3)
    torch.manual_seed(0)
    return save(get_policy_class(kind)(cfg), cfg, folder)


def vla(kind: str, folder: Path, backbone: Path) -> Path:
    return smolvla(folder, backbone) if kind == "smolvla" else paligemma_vla(kind, folder)


@pytest.mark.parametrize(("factory", "settings"), [
    (one_camera, {}), (two_cameras, {"chunk_size": 6, "n_action_steps": 3}),
], ids=["one-camera", "chunk-6"])
def test_smolvla_acts_as_in_lerobots_own_loop(tmp_path, backbone, factory, settings):
    folder = smolvla(tmp_path / "policy", backbone, cameras=len(factory().unwrapped.cameras), **settings)
    assert load_policy(str(folder)).noise_shape == (settings.get("chunk_size", 10), 32)
    same_actions_as_lerobot(folder, factory)


def first_observation() -> dict:
    obs = two_cameras().reset(seed=1_000_000)[0]
    return {"agent_pos": obs["agent_pos"][None], "environment_state": obs["environment_state"][None],
            "pixels": {k: v[None] for k, v in obs["pixels"].items()}}


VLAS = ("smolvla", "pi0", "pi05")


@pytest.mark.parametrize("kind", VLAS)
def test_a_ticket_runs_inside_lerobots_eval_and_robot_loops(tmp_path, backbone, tiny_paligemma, kind):
    """`with_ticket`'s policy in LeRobot's eval_policy gives goldenticket's episodes, and in its robot
    loop goldenticket's actions; pi0's and pi0.5's select_action takes no noise, their
    predict_action_chunk gets it."""
    folder = vla(kind, tmp_path / "policy", backbone)
    assert load_policy(str(folder)).noise_shape == (10, 32)
    same_actions_as_lerobot(folder, two_cameras)
    robot_loop_acts_as_goldenticket(folder, two_cameras)


@pytest.mark.parametrize("kind", VLAS)
def test_a_vla_ticket_fixes_its_actions_whatever_torch_draws(tmp_path, backbone, tiny_paligemma, kind):
    import torch

    policy = load_policy(str(vla(kind, tmp_path / "policy", backbone))).instructed(INSTRUCTION)
    noise = np.random.default_rng(2).standard_normal((1, *policy.noise_shape)).astype(np.float32)
    torch.manual_seed(1)
    first = policy.act(first_observation(), noise)
    torch.manual_seed(2)
    np.testing.assert_array_equal(policy.act(first_observation(), noise), first)
    assert first.shape == (1, 5, 4)


@pytest.mark.parametrize("kind", VLAS)
def test_the_instruction_is_what_the_policy_reads(tmp_path, backbone, tiny_paligemma, kind):
    policy = load_policy(str(vla(kind, tmp_path / "policy", backbone)))
    noise = np.zeros((1, *policy.noise_shape), np.float32)
    told = [policy.instructed(text).act(first_observation(), noise) for text in (INSTRUCTION, "Push it")]
    assert policy.instructed("Push it").model is policy.model  # not loaded again
    assert not np.array_equal(*told)
    assert get_task(two_cameras).instruction == INSTRUCTION and get_task(no_instruction).instruction is None


def test_a_language_policy_on_a_task_without_an_instruction_is_refused(tmp_path, backbone):
    folder = smolvla(tmp_path / "policy", backbone)
    with pytest.raises(UserError, match="reads a language instruction, and task .* gives none"):
        rollout(load_policy(str(folder)),
                get_task(no_instruction), [Episode(Constant(np.zeros((10, 32))), 1)])


def test_cameras_are_checked_by_key_as_lerobot_checks_them_and_renamed_as_it_renames_them(tmp_path,
                                                                                          backbone):
    """LeRobot's check: the env's cameras among the policy's, or the policy's among the env's; else one
    line, until rename_map maps the env's key to the policy's, as lerobot-eval's --rename_map does."""
    folder = str(smolvla(tmp_path / "policy", backbone, cameras=2))
    episode = [Episode(Constant(np.zeros((10, 32))), 1)]
    assert rollout(load_policy(folder), get_task(one_camera), episode)[0].length > 0  # one camera of two
    with pytest.raises(UserError, match=r"cameras \['observation.images.image', 'observation.images.wrist'\] "
                       r"and the policy's input features are .*neither holds the other.*--rename-map"):
        rollout(load_policy(folder), get_task(other_camera), episode)
    renamed = load_policy(folder, rename_map={"observation.images.wrist": "observation.images.image1"})
    ours = rollout(renamed, get_task(other_camera), episode, record_actions=True)[0].actions
    theirs = rollout(load_policy(folder), get_task(two_cameras), episode, record_actions=True)[0].actions
    np.testing.assert_array_equal(ours, theirs)  # the same frames, under the policy's keys


def test_a_vla_takes_frames_of_any_size_as_it_resizes_them(tmp_path, backbone):
    """SmolVLA resizes its frames itself: one declaring 128 x 128 cameras acts on 32 x 32 frames."""
    inputs, outputs = features(2)
    inputs |= {key: type(f)(f.type, (3, 128, 128)) for key, f in inputs.items() if "images" in key}
    policy = load_policy(str(tiny_smolvla(tmp_path / "policy", backbone, inputs, outputs)))
    assert rollout(policy, get_task(two_cameras), [Episode(Constant(np.zeros((10, 32))), 1)])[0].length > 0


def test_a_checkpoint_whose_backbone_is_not_on_disk_names_what_to_download(tmp_path, backbone, capsys):
    folder = smolvla(tmp_path / "policy", backbone)
    config = json.loads((folder / "config.json").read_text())
    (folder / "config.json").write_text(json.dumps(config | {"vlm_model_name": "HuggingFaceTB/SmolVLM2"}))
    assert main(["evaluate", "--policy", str(folder), "--task", "tests.test_lerobot_vla:two_cameras",
                 "--seeds", "1000000:1000002"]) == 2
    line = capsys.readouterr().err.strip()
    assert "needs the backbone 'HuggingFaceTB/SmolVLM2' on disk" in line and "hf download" in line
    assert len(line.splitlines()) == 1


def test_a_shipped_smolvla_carries_its_backbone_and_keeps_its_model_card(tmp_path, backbone):
    """The training examples' last step (examples/smolvla_recipe.py): the checkpoint with the backbone
    inside it and named relative to it, so that it runs wherever the folder goes; a card there stays."""
    from examples.smolvla_recipe import CARD, ship
    from examples.smolvla_train import RECIPE

    own = shutil.copytree(backbone, tmp_path / "backbone")
    recipe = replace(RECIPE, policy_dir=tmp_path / "shipped")
    recipe.policy_dir.mkdir()
    (recipe.policy_dir / CARD).write_text("card\n")
    ship(recipe, smolvla(tmp_path / "checkpoint", own), own)
    shutil.rmtree(own)
    moved = recipe.policy_dir.rename(tmp_path / "elsewhere")
    assert (moved / CARD).read_text() == "card\n"
    policy = load_policy(str(moved))
    assert rollout(policy, get_task(two_cameras), [Episode(Constant(np.zeros((10, 32))), 1)])[0].length > 0


def test_a_pi0_whose_tokenizer_is_not_on_disk_names_what_to_download(tmp_path, tiny_paligemma, capsys):
    """A pi0 from the hub names PaliGemma's tokenizer in its preprocessor; offline, without it cached,
    the one line says what to download."""
    folder = paligemma_vla("pi0", tmp_path / "policy")
    preprocessor = folder / "policy_preprocessor.json"
    steps = json.loads(preprocessor.read_text())
    for step in steps["steps"]:
        if step["registry_name"] == "tokenizer_processor":
            step["config"]["tokenizer_name"] = "google/paligemma-3b-pt-224"
    preprocessor.write_text(json.dumps(steps))
    assert main(["evaluate", "--policy", str(folder), "--task", "tests.test_lerobot_vla:two_cameras",
                 "--seeds", "1000000:1000002", "--workers", "1"]) == 2
    line = capsys.readouterr().err.strip()
    assert "needs the backbone 'google/paligemma-3b-pt-224' on disk" in line and "hf download" in line
    assert len(line.splitlines()) == 1


def test_env_workers_sharing_one_smolvla_give_the_results_of_one_process(tmp_path, backbone):
    """What `--device cuda` does with several workers, here on the CPU: the workers step their envs
    and act through one SmolVLA in the main process, told each task's instruction."""
    from goldenticket.noise import Gaussian
    from goldenticket.rollout import Engine

    folder, task = str(smolvla(tmp_path / "policy", backbone)), get_task(two_cameras)
    episodes = [Episode(Gaussian(), s) for s in range(1_000_000, 1_000_008)]
    with Engine(folder, task) as alone, \
            Engine(folder, task, workers=2, shard_size=4, share_model=True) as shared:
        results = [[(r.success, r.ret, r.length) for r in e.evaluate(episodes)] for e in (alone, shared)]
    assert results[0] == results[1]


def test_a_smolvla_is_searched_and_judged_through_the_cli_on_a_camera_task(tmp_path, backbone):
    """A built-in camera task gives its frame, the hand's state and its instruction; 1 and 2 workers agree."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (4,)),
              "observation.image": PolicyFeature(FeatureType.VISUAL, (3, 64, 64))}
    folder = smolvla(tmp_path / "policy", backbone, input_features=inputs)
    runs = []
    for workers in ("1", "2"):
        out = tmp_path / f"run-{workers}"
        assert main(["search", "--policy", str(folder), "--task", "metaworld-pixels/reach-v3",
                     "--max-steps", "16", "--method", "rs", "--budget", "4", "--search-seeds", "2",
                     "--validation-seeds", "0", "--heldout", "4", "--top-k", "1", "--workers", workers,
                     "--out", str(out)]) == 0
        summary = json.loads((out / "summary.json").read_text())
        runs.append(json.loads(json.dumps(summary).replace(str(out), "OUT")))
    assert runs[0]["base"]["n"] == 4
    for key in ("base", "zero", "tickets", "validation_scores"):
        assert runs[0].get(key) == runs[1].get(key)


def test_the_shipped_smolvla_ticket_gives_lerobots_per_episode_successes():
    """The shipped SmolVLA and its drawer-open ticket in LeRobot's own eval loop (select_action with
    the ticket, the instruction from the env) and in goldenticket's engine: the same episodes succeed."""
    import torch

    from examples.lerobot_eval import EXAMPLES, goldenticket_successes, lerobot_successes
    from goldenticket.tickets import Ticket

    folder, tickets = EXAMPLES["smolvla"]
    (task, ticket_file), = tickets.items()
    policy, seeds = load_policy(str(folder)), range(1_005_000, 1_005_016)
    ticket = torch.from_numpy(Ticket.load(ticket_file, expected_shape=policy.noise_shape).noise)
    ours = goldenticket_successes(policy, ticket, task, seeds)
    assert ours == lerobot_successes(policy, ticket, task, seeds) and sum(ours) > 0

"""LeRobot checkpoints as policies (goldenticket.policies.lerobot).

The refusals run everywhere; the tests marked `lerobot` need LeRobot 0.6.1, installed in its own
venv (README, "LeRobot"; .ci/run runs them there) and are skipped without it.
"""

import importlib.util
import json
import pickle
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import BUNDLED_DIR, load_policy
from goldenticket.policies.lerobot import is_checkpoint
from goldenticket.rollout import Engine, Episode, rollout
from goldenticket.tasks import get_task
from goldenticket.tickets import Ticket

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT))  # examples.lerobot_reach, here and in worker processes
from examples.lerobot_reach import make_env, make_vector_env  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from lerobot_checks import (  # noqa: E402
    CameraReach,
    lerobot_loop,
    robot_loop_acts_as_goldenticket,
    same_actions_as_lerobot,
)
from lerobot_models import in_hub_cache  # noqa: E402

HAS_LEROBOT = importlib.util.find_spec("lerobot") is not None
SHIPPED = ROOT / "examples" / "lerobot_reach_policy"
BUTTON = ROOT / "examples" / "lerobot_button_policy"
TICKET = ROOT / "examples" / "lerobot_reach_ticket.safetensors"
REACH = "examples.lerobot_reach:make_env"


def needs_lerobot(test):
    """Marked `lerobot` (`pytest -m lerobot`), skipped where LeRobot is not installed."""
    reason = "LeRobot is not installed (it has its own venv: README, \"LeRobot\")"
    return pytest.mark.lerobot(pytest.mark.skipif(not HAS_LEROBOT, reason=reason)(test))


def fake_checkpoint(folder: Path, **config) -> Path:
    """A folder with LeRobot's file names, holding no real weights."""
    folder.mkdir()
    config = {"type": "diffusion", "noise_scheduler_type": "DDIM"} | config
    (folder / "config.json").write_text(json.dumps(config))
    for name in ("model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
        (folder / name).write_text("{}")
    return folder


def refusal(capsys, policy: str) -> str:
    """The one line `goldenticket evaluate` prints for `policy`, once it exited with code 2."""
    assert main(["evaluate", "--policy", policy, "--task", REACH, "--seeds", "1000000:1000002"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    return lines[0]


@pytest.mark.parametrize(("config", "says"), [
    ({"type": "act"}, "type 'act' takes no initial noise"),
    ({"type": "vqbet"}, "type 'vqbet' takes no initial noise"),
    ({"type": "tdmpc"}, "type 'tdmpc' takes no initial noise"),
    ({"type": "groot"}, "type 'groot' draws its noise inside"),
    ({"noise_scheduler_type": "DDPM"}, 'set "noise_scheduler_type": "DDIM"'),
])
def test_policies_a_ticket_cannot_steer_are_refused(tmp_path, capsys, config, says):
    assert says in refusal(capsys, str(fake_checkpoint(tmp_path / "policy", **config)))


def test_a_folder_missing_lerobot_files_is_not_a_checkpoint(tmp_path, capsys):
    folder = fake_checkpoint(tmp_path / "policy")
    (folder / "model.safetensors").unlink()
    assert "is not a LeRobot checkpoint: no model.safetensors" in refusal(capsys, str(folder))


def test_lerobot_folders_are_told_from_goldenticket_ones(tmp_path):
    assert is_checkpoint(fake_checkpoint(tmp_path / "policy"))
    assert not is_checkpoint(BUNDLED_DIR / "metaworld/reach-v3/ddim")
    assert not is_checkpoint(tmp_path / "nothing-here")


@pytest.mark.skipif(HAS_LEROBOT, reason="checks the message shown where LeRobot is not installed")
def test_without_lerobot_a_checkpoint_says_how_to_install_it(tmp_path, capsys):
    assert "LeRobot is not installed here" in refusal(capsys, str(fake_checkpoint(tmp_path / "policy")))


# --- with LeRobot ------------------------------------------------------------------------------

def make_pixel_env() -> gym.Env:
    return gym.wrappers.TimeLimit(CameraReach(), 40)


def lerobot_checkpoint(folder: Path, *, images: bool = False, **config) -> Path:
    """An untrained LeRobot DiffusionPolicy folder, written by LeRobot's own save_pretrained."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
    from lerobot.policies.diffusion.processor_diffusion import make_diffusion_pre_post_processors

    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (4,)),
              "observation.environment_state": PolicyFeature(FeatureType.ENV, (6,))}
    if images:
        inputs["observation.image"] = PolicyFeature(FeatureType.VISUAL, (3, 64, 64))
    settings = {"down_dims": (16, 32), "diffusion_step_embed_dim": 16, "noise_scheduler_type": "DDIM",
                "num_inference_steps": 3, "horizon": 8, "n_action_steps": 4, "crop_shape": None,
                "device": "cpu", "push_to_hub": False, "pretrained_backbone_weights": None} | config
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (4,))}
    cfg = DiffusionConfig(input_features=inputs, output_features=outputs, **settings)
    torch.manual_seed(0)
    DiffusionPolicy(cfg).save_pretrained(folder)
    span = {"min": torch.tensor([-0.5, 0.3, 0.0, -1.0]), "max": torch.tensor([0.5, 0.9, 0.3, 1.0])}
    stats = {"observation.state": span, "action": {"min": -torch.ones(4), "max": torch.ones(4)},
             "observation.image": {"mean": torch.full((3, 1, 1), 0.1), "std": torch.full((3, 1, 1), 0.3)}}
    for pipeline in make_diffusion_pre_post_processors(cfg, stats):
        pipeline.save_pretrained(folder)
    return folder


@pytest.mark.parametrize(("settings", "factory"), [
    ({"n_obs_steps": 2}, make_env),
    ({"n_obs_steps": 1, "horizon": 16, "n_action_steps": 6}, make_env),
    ({"n_obs_steps": 2, "images": True}, make_pixel_env),
], ids=["history-2", "no-history", "images"])
@needs_lerobot
def test_actions_are_those_of_lerobots_own_loop(tmp_path, settings, factory):
    """Every executed action of every episode, bitwise, as select_action(batch, noise=ticket) gives
    them in lerobot-eval's rollout: per-episode history, LeRobot's pre- and postprocessing."""
    same_actions_as_lerobot(lerobot_checkpoint(tmp_path / "policy", **settings), factory)


@pytest.mark.slow
@needs_lerobot
def test_a_ticket_runs_inside_lerobots_robot_loop(tmp_path):
    """`with_ticket`'s diffusion policy, one robot in LeRobot's robot loop: select_action keeps the last
    2 frames of camera and state, and acts as goldenticket does on that history."""
    robot_loop_acts_as_goldenticket(lerobot_checkpoint(tmp_path / "policy", images=True), make_pixel_env)


@needs_lerobot
def test_shipped_ticket_gives_lerobots_per_episode_successes():
    """goldenticket's engine and LeRobot's eval loop, on the same held-out seeds with the shipped
    ticket, succeed on the same episodes."""
    policy = load_policy(str(SHIPPED))
    ticket = Ticket.load(TICKET, expected_shape=policy.noise_shape).noise
    seeds = list(range(1_005_000, 1_005_032))
    with Engine(policy, get_task(REACH), loaded=policy) as engine:
        ours = [r.success for r in engine.evaluate([Episode(Constant(ticket), s) for s in seeds])]
    from lerobot.scripts.lerobot_eval import eval_policy

    info = eval_policy(*lerobot_loop(policy, ticket, make_env), n_episodes=len(seeds), start_seed=seeds[0])
    assert ours == [e["success"] for e in info["per_episode"]]
    assert 0 < sum(ours) < len(seeds)


@needs_lerobot
def test_a_checkpoint_is_one_deterministic_policy_however_reached(tmp_path):
    """The same folder by path or @N steps, pickled, alone or in a batch, in worker processes: the
    same fingerprint and the same actions."""
    folder = str(lerobot_checkpoint(tmp_path / "policy"))
    policy, faster = load_policy(folder), load_policy(folder + "@2")
    assert (policy.noise_shape, policy.n_exec) == ((8, 4), 4)
    assert policy.fingerprint().endswith("steps3") and faster.fingerprint().endswith("steps2")
    copy = pickle.loads(pickle.dumps(policy))
    assert copy.fingerprint() == policy.fingerprint()
    task = get_task(REACH, max_steps=30)
    episodes = [Episode(Gaussian(), s) for s in range(1_000_000, 1_000_020)]
    together = rollout(policy, task, episodes, record_actions=True)
    for episode, result in zip(episodes[:3], together, strict=False):
        np.testing.assert_array_equal(rollout(copy, task, [episode], record_actions=True)[0].actions,
                                      result.actions)
    with Engine(folder, task, workers=2, shard_size=7) as engine:
        in_workers = engine.evaluate(episodes)
    assert [(r.success, r.length) for r in in_workers] == [(r.success, r.length) for r in together]


@needs_lerobot
def test_a_checkpoint_is_searched_through_the_api_and_resumed(tmp_path):
    """goldenticket.search(DIR, ...) writes the verdict and the run store; the same call resumes
    from the store and gives the same summary."""
    import goldenticket

    folder = str(lerobot_checkpoint(tmp_path / "policy"))
    options = {"method": "rs", "budget": 8, "search_seeds": 2, "validation_seeds": 0, "heldout": 16,
               "top_k": 1, "max_steps": 20, "workers": 1}
    first = goldenticket.search(folder, REACH, tmp_path / "run", **options)
    assert first.run.policy == folder and first.base.rate.n == 16
    ticket = Ticket.load(Path(first.best.path), expected_shape=(8, 4))
    assert ticket.metadata["policy_fingerprint"] == load_policy(folder).fingerprint()
    assert goldenticket.search(folder, REACH, tmp_path / "run", **options) == first


@needs_lerobot
def test_observations_without_the_input_features_are_refused(tmp_path):
    policy = load_policy(str(lerobot_checkpoint(tmp_path / "policy", images=True)))
    with pytest.raises(UserError, match="reads camera 'observation.image', and the env's cameras are \\[\\]"):
        rollout(policy, get_task(REACH), [Episode(Gaussian(), 1_000_000)])


@needs_lerobot
def test_a_hub_repo_id_loads_its_snapshot_from_the_hub_cache(tmp_path, monkeypatch):
    """`--policy owner/name`, as lerobot-eval's --policy.path takes it: huggingface_hub's snapshot in the
    cache (offline here), the same policy as its folder, named by the repo id."""
    from huggingface_hub import constants

    from goldenticket.zoo import bundled_task

    folder = lerobot_checkpoint(tmp_path / "policy")
    in_hub_cache(tmp_path / "hub", "someone/reach-diffusion", folder)
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)
    policy = load_policy("someone/reach-diffusion@2")
    assert policy.name == "someone/reach-diffusion@2" and policy.denoising_steps == 2
    assert policy.fingerprint() == load_policy(f"{folder}@2").fingerprint()
    assert bundled_task("someone/reach-diffusion") is None


@pytest.mark.slow
@needs_lerobot
def test_n_action_steps_is_overridden_as_lerobot_eval_does(tmp_path, capsys):
    """policy_override n_action_steps=N: N actions a call, another fingerprint, recorded in the ticket,
    which then runs as found; a value the model cannot take, or another setting, is one line."""
    folder = str(lerobot_checkpoint(tmp_path / "policy"))  # horizon 8, 2 observed steps: at most 7
    policy, saved = load_policy(folder, overrides={"n_action_steps": 6}), load_policy(folder)
    assert policy.n_exec == 6 and policy.fingerprint() == saved.fingerprint() + "-n_action_steps6"
    assert pickle.loads(pickle.dumps(policy)).n_exec == 6
    assert load_policy(folder, overrides={"n_action_steps": 4}).fingerprint() == saved.fingerprint()
    for override, says in (({"n_action_steps": 8}, "integer from 1 to 7"),
                           ({"horizon": 16}, "goldenticket changes n_action_steps")):
        with pytest.raises(UserError, match=says):
            load_policy(folder, overrides=override)
    out = tmp_path / "run"
    assert main(["search", "--policy", folder, "--task", REACH, "--policy-override", "n_action_steps=6",
                 "--method", "rs", "--budget", "2", "--search-seeds", "1", "--validation-seeds", "0",
                 "--heldout", "2", "--top-k", "1", "--max-steps", "12", "--workers", "1",
                 "--out", str(out)]) == 0
    ticket = next((out / "tickets").glob("*.safetensors"))
    assert Ticket.load(ticket).metadata["policy_override"] == {"n_action_steps": 6}
    capsys.readouterr()
    assert main(["evaluate", "--policy", folder, "--ticket", str(ticket), "--task", REACH,
                 "--max-steps", "12", "--seeds", "1000000:1000002", "--workers", "1", "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)) == {"base", "zero", Ticket.load(ticket).id}


MARKER_STEP = """\
import pathlib
pathlib.Path(__file__).with_name("imported").touch()

class Step:
    def __init__(self, **config):
        pass
"""


class PluginStep:
    """A processor step registered outside LeRobot."""

    def __init__(self, **config):
        pass


@pytest.mark.parametrize(("step", "says"), [
    ({"class": "gt_marker_step.Step", "config": {}},
     "step 0 names the import path 'gt_marker_step.Step'; goldenticket loads only the processor steps "
     "LeRobot registers, named by \"registry_name\""),
    ({"registry_name": "gt_plugin_step", "config": {}},
     "step 0 'gt_plugin_step' is no processor step LeRobot registers"),
], ids=["import path", "not lerobot's"])
@needs_lerobot
def test_a_processor_step_lerobot_does_not_register_is_refused_before_any_runs(tmp_path, monkeypatch, step,
                                                                                 says):
    """A saved processor naming a class to import, or a step registered outside LeRobot, is one line
    naming the file and the step; nothing it names is imported."""
    from lerobot.processor import ProcessorStepRegistry

    (tmp_path / "gt_marker_step.py").write_text(MARKER_STEP)  # importing it leaves a file beside it
    monkeypatch.syspath_prepend(str(tmp_path))
    folder = lerobot_checkpoint(tmp_path / "policy")
    preprocessor = folder / "policy_preprocessor.json"
    pipeline = json.loads(preprocessor.read_text())
    pipeline["steps"].insert(0, step)
    preprocessor.write_text(json.dumps(pipeline))
    ProcessorStepRegistry.register("gt_plugin_step")(PluginStep)
    try:
        with pytest.raises(UserError) as error:
            load_policy(str(folder))
    finally:
        ProcessorStepRegistry.unregister("gt_plugin_step")
    assert str(error.value) == f"{preprocessor}: {says}"
    assert not (tmp_path / "imported").exists()


@needs_lerobot
def test_the_steps_lerobot_registers_are_those_its_checkpoints_name():
    from goldenticket.policies.lerobot.checkpoint import check_processors, lerobot_steps

    steps = lerobot_steps()
    for folder in (SHIPPED, BUTTON, ROOT / "examples" / "smolvla_metaworld_policy"):
        check_processors(folder, steps, needed=("device_processor",))
    assert {"pi0_new_line_processor", "pi05_prepare_state_tokenizer_processor_step"} <= steps


def test_the_example_env_is_what_lerobot_eval_runs():
    """make_vector_env gives lerobot-eval's autoreset and the 150-step limit rollout reads."""
    env = make_vector_env(2)
    assert env.call("_max_episode_steps") == (150, 150)
    obs, _ = env.reset(seed=[1_000_000, 1_000_001])
    assert obs["agent_pos"].shape == (2, 4) and obs["environment_state"].shape == (2, 6)


@needs_lerobot
def test_the_button_example_and_its_ticket_act_in_their_env(capsys):
    """The button policy reads its env's observations; its shipped ticket succeeds more often than
    fresh noise there (88% against 31% on 300 fresh seeds)."""
    assert main(["evaluate", "--policy", str(BUTTON), "--task", "examples.lerobot_button:make_env",
                 "--ticket", str(BUTTON.with_name("lerobot_button_ticket.safetensors")),
                 "--seeds", "1005000:1005016", "--workers", "1", "--json"]) == 0
    rates = {arm: row["success_rate"] for arm, row in json.loads(capsys.readouterr().out).items()}
    assert 0 < rates["base"] < rates["b49c6a1b5fad"]


@needs_lerobot
def test_evaluate_json_is_json_alone(capsys):
    """LeRobot prints where it loads weights from: none of it reaches stdout, where --json goes."""
    assert main(["evaluate", "--policy", str(SHIPPED), "--task", REACH, "--seeds", "1005000:1005002",
                 "--workers", "1", "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)) == {"base", "zero"}

"""Camera tasks (`metaworld-pixels/`) and policies that see their frames."""

import dataclasses

import numpy as np
import pytest
import torch

from goldenticket import checks
from goldenticket.errors import UserError
from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import MLPPolicy, PolicyConfig
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task
from goldenticket.tasks import pixels as pixels_module
from goldenticket.tasks.base import stack
from goldenticket.train import DemoStyle, collect_demos, shifted, train_policy

TASK = "metaworld-pixels/drawer-open-v3"


def tiny_image_policy(seed: int = 0) -> MLPPolicy:
    torch.manual_seed(seed)
    return MLPPolicy(PolicyConfig("tiny-pixels", "flow", 4, 4, hidden=32, layers=1, steps=2,
                                  image_size=pixels_module.SIZE))


def test_frames_are_a_function_of_seed_and_actions():
    env = get_task(TASK).make_env()
    first = env.reset(3)
    assert first["pixels"].shape == (64, 64, 3) and first["pixels"].dtype == np.uint8
    assert first["agent_pos"].shape == (4,) and first["agent_pos"].dtype == np.float32
    after = env.step(np.full(4, 0.5))[0]
    env.reset(4)
    assert not np.array_equal(env.reset(4)["pixels"], first["pixels"])  # another drawer position
    again = env.reset(3)
    assert np.array_equal(again["pixels"], first["pixels"])
    assert np.array_equal(env.step(np.full(4, 0.5))[0]["pixels"], after["pixels"])
    assert not np.array_equal(after["pixels"], first["pixels"])  # the hand moved


def test_skipping_unseen_frames_changes_no_episode():
    """rollout draws only the frames the policy reads; the episodes are those of drawing all."""
    class DrawsEveryFrame:
        def __init__(self, env):
            self.reset, self.step = env.reset, env.step

    task = dataclasses.replace(get_task(TASK), max_steps=12)
    policy = tiny_image_policy()
    episodes = [Episode(Gaussian(0), seed) for seed in (0, 1, 2)]
    skipping = rollout(policy, task, episodes, record_actions=True)
    drawing = rollout(policy, task, episodes, envs=[DrawsEveryFrame(task.make_env()) for _ in episodes],
                      record_actions=True)
    assert [r.length for r in skipping] == [12, 12, 12]
    for a, b in zip(skipping, drawing, strict=True):
        assert np.array_equal(a.actions, b.actions) and a.digest == b.digest


def test_check_refuses_frames_that_vary(monkeypatch):
    task = get_task(TASK)
    checks.require(task)
    drawn = iter(range(10**6))
    original = pixels_module.PixelsEnv._observed

    def flickering(self, state):
        obs = original(self, state)
        obs["pixels"][0, 0, 0] = next(drawn) % 256
        return obs

    monkeypatch.setattr(pixels_module.PixelsEnv, "_observed", flickering)
    with pytest.raises(UserError, match=r"does not fix the initial state \(.*: its 'pixels' differ\)"):
        checks.require(task)


def test_a_renderer_with_a_display_backend_is_one_line(monkeypatch):
    pixels_module.pixel_task_names()  # MuJoCo imported as goldenticket imports it, with EGL
    from mujoco import gl_context

    class OnScreen:
        __module__ = "mujoco.glfw"

    monkeypatch.setattr(gl_context, "GLContext", OnScreen)
    pixels_module._renderer.cache_clear()
    try:
        with pytest.raises(UserError, match="MUJOCO_GL=egl.*libegl1"):
            pixels_module._renderer("drawer-close-v3")
    finally:
        pixels_module._renderer.cache_clear()


def test_an_image_policy_refuses_frames_off_its_contract():
    policy, noise = tiny_image_policy(), np.zeros((2, 8, 4), np.float32)
    frames = {"pixels": np.zeros((2, 64, 64, 3), np.uint8), "agent_pos": np.zeros((2, 4), np.float32)}
    assert policy.act(frames, noise).shape == (2, 4, 4)
    small = np.zeros((2, 32, 32, 3), np.uint8)
    wrong = [({**frames, "pixels": small}, r"uint8 \[B, 64, 64, 3\], got uint8 \[2, 32"),
             ({**frames, "pixels": frames["pixels"].astype(np.float32)}, "got float32"),
             ({"pixels": frames["pixels"]}, "dicts with 'pixels' and 'agent_pos', got \\['pixels'\\]"),
             (np.zeros((2, 39), np.float32), "got ndarray"),
             ({**frames, "agent_pos": np.zeros((2, 39))}, r"'agent_pos' must be \[B, 4\]")]
    for obs, message in wrong:
        with pytest.raises(UserError, match=message):
            policy.act(obs, noise)


def test_an_image_policy_acts_on_each_row_as_if_alone():
    policy, env = tiny_image_policy(), get_task(TASK).make_env()
    frames = stack([env.reset(seed) for seed in range(20)])
    noise = np.random.default_rng(0).standard_normal((20, 8, 4)).astype(np.float32)
    together = policy.act(frames, noise)
    for i in (0, 17, 19):
        alone = policy.act({k: v[i : i + 1] for k, v in frames.items()}, noise[i : i + 1])
        assert np.array_equal(alone[0], together[i])


def test_shifted_frames_stay_in_the_frame_and_move():
    frames = torch.arange(2 * 8 * 8 * 3, dtype=torch.uint8).reshape(2, 8, 8, 3)
    moved = shifted(frames, torch.Generator().manual_seed(0))
    assert moved.shape == (2, 8, 8, 3) and moved.dtype == torch.float32
    again = shifted(frames, torch.Generator().manual_seed(0))
    assert torch.equal(moved, again) and not torch.equal(moved, frames.float())


def test_demos_and_image_training_are_deterministic_for_a_seed():
    task = get_task(TASK)
    demos = collect_demos(task, 1, DemoStyle(), seed=0)
    assert demos.obs[0]["pixels"].shape[1:] == (64, 64, 3)
    cfg = tiny_image_policy().cfg
    (a, loss_a), (b, loss_b) = (train_policy(cfg, demos, steps=3, batch=4, seed=1) for _ in range(2))
    assert a.weights_hash() == b.weights_hash() and loss_a == loss_b
    ticket = Constant(np.zeros(a.noise_shape, np.float32))
    assert rollout(a, dataclasses.replace(task, max_steps=8), [Episode(ticket, 1_000_000)])[0].length == 8


@pytest.mark.slow
def test_an_image_search_from_the_cli(tmp_path, capsys):
    """The bundled image policy's search end to end, on two worker processes, then its tickets
    evaluated from the run folder alone."""
    from goldenticket.cli import main

    out = tmp_path / "run"
    assert main(["search", "--policy", f"{TASK}/flow", "--task", TASK, "--budget", "32", "--heldout", "16",
                 "--max-steps", "40", "--workers", "2", "--out", str(out)]) == 0
    tickets = sorted((out / "tickets").glob("*.safetensors"))
    assert tickets and (out / "summary.json").is_file()
    capsys.readouterr()
    assert main(["evaluate", "--policy", f"{TASK}/flow", "--ticket", str(tickets[0]),
                 "--seeds", "1000000:1000016"]) == 0
    assert "base" in capsys.readouterr().out


@pytest.mark.slow
def test_an_image_policy_on_a_state_task_is_one_line(capsys):
    from goldenticket.cli import main

    assert main(["evaluate", "--policy", f"{TASK}/flow", "--task", "metaworld/drawer-open-v3",
                 "--seeds", "1000000:1000002"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "goldenticket: error" in line]
    assert len(errors) == 1 and "sees images" in errors[0]


@pytest.mark.slow
def test_a_state_policy_on_a_camera_task_is_one_line(capsys):
    from goldenticket.cli import main

    assert main(["evaluate", "--policy", "metaworld/drawer-open-v3/flow", "--task", TASK,
                 "--seeds", "1000000:1000002"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "goldenticket: error" in line]
    assert len(errors) == 1 and "sees state vectors [B, 39]" in errors[0] and "'pixels'" in errors[0]

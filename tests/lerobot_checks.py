"""What the LeRobot tests share: the reach env with camera frames (a picture of the hand's position, as
one `pixels` array, `observation.image`, or a dict of named cameras, `observation.images.*`), and
LeRobot's own eval loop to hold a checkpoint's actions against."""

import inspect
from functools import partial
from pathlib import Path

import gymnasium as gym
import numpy as np

from examples.lerobot_reach import LeRobotReach
from goldenticket.noise import Constant
from goldenticket.policies import load_policy
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task


class CameraReach(LeRobotReach):
    """reach-v3 seen in `size` px frames: one `pixels` array where `cameras` is empty, else a dict of
    those cameras (each shifted by its index); with LeRobot's instruction attribute `task_description`."""

    size, cameras = 64, ()
    task_description = "Reach a goal position"

    def __init__(self):
        super().__init__()
        frame = gym.spaces.Box(0, 255, (self.size, self.size, 3), np.uint8)
        pixels = gym.spaces.Dict({c: frame for c in self.cameras}) if self.cameras else frame
        self.observation_space = gym.spaces.Dict({**LeRobotReach.observation_space.spaces, "pixels": pixels})

    def seen(self, obs: dict) -> dict:
        frame = np.zeros((self.size, self.size, 3), np.uint8)
        row, col = np.clip(((obs["agent_pos"][:2] + 0.5) * self.size).astype(int), 0, self.size - 4)
        frame[row : row + 4, col : col + 4] = 255
        if not self.cameras:
            return obs | {"pixels": frame}
        return obs | {"pixels": {c: np.roll(frame, i, axis=0) for i, c in enumerate(self.cameras)}}

    def reset(self, seed=None, options=None):
        obs, info = super().reset(seed=seed)
        return self.seen(obs), info

    def step(self, action):
        obs, *rest = super().step(action)
        return self.seen(obs), *rest


def lerobot_loop(policy, ticket: np.ndarray, env_factory) -> tuple:
    """What lerobot-eval's `rollout` and `eval_policy` take after the env: 16 envs, the model answering
    `select_action(batch)` with the ticket as its noise (passed to `select_action`, or where that takes
    none, pi0's and pi0.5's, to the `predict_action_chunk` it calls), no env processing, the policy's
    pre- and postprocessor."""
    import torch
    from lerobot.processor import PolicyProcessorPipeline

    model, identity = policy.model, PolicyProcessorPipeline(steps=[])
    noise = torch.from_numpy(ticket).expand(16, *ticket.shape)
    method = "select_action" if "noise" in inspect.signature(model.select_action).parameters \
        else "predict_action_chunk"
    setattr(model, method, partial(getattr(type(model), method), model, noise=noise))
    env = gym.vector.SyncVectorEnv([env_factory] * 16, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    return env, model, identity, identity, policy.preprocessor, policy.postprocessor


def same_actions_as_lerobot(folder: Path, factory) -> None:
    """Every executed action of 16 episodes, bitwise, as LeRobot's eval loop gives them."""
    from lerobot.scripts.lerobot_eval import rollout as lerobot_rollout

    policy = load_policy(str(folder))
    ticket = np.random.default_rng(1).standard_normal(policy.noise_shape).astype(np.float32)
    seeds = list(range(1_000_000, 1_000_016))
    episodes = [Episode(Constant(ticket), s) for s in seeds]
    ours = rollout(policy, get_task(factory), episodes, record_actions=True)
    theirs = lerobot_rollout(*lerobot_loop(policy, ticket, factory), seeds=seeds)["action"].numpy()
    for episode, result in enumerate(ours):
        np.testing.assert_array_equal(result.actions, theirs[episode, : result.length])

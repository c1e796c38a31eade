"""What the LeRobot tests share: the reach env with camera frames (a picture of the hand's position, as
one `pixels` array, `observation.image`, or a dict of named cameras, `observation.images.*`), and
LeRobot's own eval and robot loops, running `with_ticket`'s policy, to hold a checkpoint's actions
against."""

from pathlib import Path

import gymnasium as gym
import numpy as np

from examples.lerobot_reach import LeRobotMetaWorld
from goldenticket.noise import Constant
from goldenticket.policies import load_policy
from goldenticket.policies.lerobot import with_ticket
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task


class CameraReach(LeRobotMetaWorld):
    """reach-v3 seen in `size` px frames: one `pixels` array where `cameras` is empty, else a dict of
    those cameras (each shifted by its index); with LeRobot's instruction attribute `task_description`."""

    size, cameras = 64, ()
    task_description = "Reach a goal position"

    def __init__(self):
        super().__init__()
        frame = gym.spaces.Box(0, 255, (self.size, self.size, 3), np.uint8)
        pixels = gym.spaces.Dict({c: frame for c in self.cameras}) if self.cameras else frame
        state = LeRobotMetaWorld.observation_space.spaces
        self.observation_space = gym.spaces.Dict({**state, "pixels": pixels})

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
    """What lerobot-eval's `rollout` and `eval_policy` take after the env: 16 envs, the model with the
    ticket (`with_ticket`), no env processing, the policy's pre- and postprocessor."""
    from lerobot.processor import PolicyProcessorPipeline

    model, identity = with_ticket(policy.model, ticket), PolicyProcessorPipeline(steps=[])
    env = gym.vector.SyncVectorEnv([env_factory] * 16, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    return env, model, identity, identity, policy.preprocessor, policy.postprocessor


def same_actions_as_lerobot(folder: Path, factory) -> None:
    """16 episodes with a ticket in LeRobot's `eval_policy` (the loop behind lerobot-eval) and in
    goldenticket's rollout (what its engine runs): the same successes, and every executed action
    bitwise the same."""
    import torch
    from lerobot.scripts.lerobot_eval import eval_policy

    policy = load_policy(str(folder))
    ticket = np.random.default_rng(1).standard_normal(policy.noise_shape).astype(np.float32)
    seeds = range(1_000_000, 1_000_016)
    episodes = [Episode(Constant(ticket), s) for s in seeds]
    ours = rollout(policy, get_task(factory), episodes, record_actions=True)
    *loop, postprocessor = lerobot_loop(policy, ticket, factory)
    taken = []

    def recorded(action):  # the actions eval_policy sends to the envs, step by step
        taken.append(postprocessor(action))
        return taken[-1]

    info = eval_policy(*loop, recorded, n_episodes=len(seeds), start_seed=seeds.start)
    assert [episode["success"] for episode in info["per_episode"]] == [result.success for result in ours]
    for result, actions in zip(ours, torch.stack(taken, dim=1).numpy(), strict=True):
        np.testing.assert_array_equal(result.actions, actions[: result.length])


def robot_frame(obs: dict) -> dict:
    """An env observation as a robot loop's frame (`build_dataset_frame`): float32 state and (H, W, C)
    uint8 images under the dataset's keys."""
    frame = {"observation.state": obs["agent_pos"].astype(np.float32),
             "observation.environment_state": obs["environment_state"].astype(np.float32)}
    pixels = obs.get("pixels")
    if isinstance(pixels, dict):
        return frame | {f"observation.images.{camera}": image for camera, image in pixels.items()}
    return frame if pixels is None else frame | {"observation.image": pixels}


def robot_loop_acts_as_goldenticket(folder: Path, factory, seed: int = 1_000_000) -> None:
    """At every step of goldenticket's episode with a ticket, LeRobot's robot loop for one robot
    (`reset()`, then at each step `predict_action`: a batch of one frame, the preprocessor,
    `select_action`, the postprocessor) on `with_ticket`'s policy, given that step's observation,
    gives the action goldenticket took, to float32 rounding: goldenticket computes a robot's row in
    a block of 16, which rounds the last bits as LeRobot's batch of 16 envs does, not as a batch of
    one."""
    import torch
    from lerobot.common.control_utils import predict_action

    policy, task = load_policy(str(folder)), get_task(factory)
    ticket = np.random.default_rng(1).standard_normal(policy.noise_shape).astype(np.float32)
    ours = rollout(policy, task, [Episode(Constant(ticket), seed)], record_actions=True)[0].actions
    robot, env = with_ticket(policy.model, ticket), factory()
    robot.reset()
    obs, theirs = env.reset(seed=seed)[0], []
    for action in ours:
        theirs.append(predict_action(robot_frame(obs), robot, torch.device("cpu"), policy.preprocessor,
                                     policy.postprocessor, use_amp=False, task=task.instruction)[0].numpy())
        obs = env.step(action)[0]
    np.testing.assert_allclose(theirs, ours, rtol=1e-5, atol=1e-5)

"""Meta-World reach-v3 (and button-press-topdown-v3: `lerobot_button.py`) as a Gymnasium env in
LeRobot's observation format, for the LeRobot diffusion policy in `lerobot_reach_policy/` (trained
by `lerobot_train.py`). From the repository root, in the LeRobot venv (README, "LeRobot"):

    goldenticket search --policy examples/lerobot_reach_policy --task examples.lerobot_reach:make_env \
        --out runs/lerobot-reach

The env is goldenticket's seeded `metaworld/reach-v3` (reset(seed) fixes hand, puck and goal)
with LeRobot's keys: `agent_pos` (hand xyz and gripper opening) and `environment_state` (puck xyz
and goal xyz), which LeRobot's `preprocess_observation` turns into `observation.state` and
`observation.environment_state`. An episode terminates on success (`info["is_success"]`) and is
truncated after 150 steps, as LeRobot's own envs do, so `lerobot-eval`'s rollout runs it as is.
"""

import gymnasium as gym
import numpy as np

from goldenticket.tasks.metaworld import MetaWorldEnv

MAX_STEPS = 150
STATE, ENV_STATE = slice(0, 4), np.r_[4:7, 36:39]  # of Meta-World's 39 observation values


def split(obs: np.ndarray) -> dict[str, np.ndarray]:
    """Meta-World's observation [39] -> LeRobot's {"agent_pos": [4], "environment_state": [6]}."""
    return {"agent_pos": obs[STATE].copy(), "environment_state": obs[ENV_STATE].copy()}


class LeRobotMetaWorld(gym.Env):
    """A Meta-World task (reach-v3: move the hand to the goal; `info["is_success"]` as Meta-World
    judges it) with its first object's xyz and the goal's as `environment_state`."""

    metadata = {"render_fps": 80}  # Meta-World's control rate
    observation_space = gym.spaces.Dict({
        "agent_pos": gym.spaces.Box(-np.inf, np.inf, (4,), np.float32),
        "environment_state": gym.spaces.Box(-np.inf, np.inf, (6,), np.float32),
    })
    action_space = gym.spaces.Box(-1, 1, (4,), np.float32)

    def __init__(self, task: str = "reach-v3"):
        self.env = MetaWorldEnv(task)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        return split(self.env.reset(int(seed or 0))), {"is_success": False}

    def step(self, action):
        obs, success, done = self.env.step(np.asarray(action, dtype=np.float64))
        return split(obs), float(success), success, done, {"is_success": success}


def make_env(task: str = "reach-v3") -> gym.Env:
    return gym.wrappers.TimeLimit(LeRobotMetaWorld(task), MAX_STEPS)


def make_vector_env(n: int) -> gym.vector.SyncVectorEnv:
    """`n` envs as LeRobot's `make_env` builds them for `lerobot-eval` (autoreset in the same step)."""
    return gym.vector.SyncVectorEnv([make_env] * n, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)

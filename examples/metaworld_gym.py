"""A built-in Meta-World camera task as the Gymnasium env LeRobot's eval loop runs: goldenticket's
seeded `metaworld-pixels/<env>` (reset(seed) fixes the initial state) with LeRobot's keys (`pixels`,
`agent_pos`), `info["is_success"]`, the task's instruction as `task_description`, 150 steps."""

import gymnasium as gym
import numpy as np

from goldenticket.tasks import get_task


class MetaWorldCameraGym(gym.Env):
    """`metaworld-pixels/<env>` behind Gymnasium's API; an episode terminates on success."""

    metadata = {"render_fps": 80}

    def __init__(self, task: str):
        self._task = get_task(task)
        self._env, self.task_description = self._task.make_env(), self._task.instruction
        self.observation_space = gym.spaces.Dict({
            "pixels": gym.spaces.Box(0, 255, (64, 64, 3), np.uint8),
            "agent_pos": gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)})
        self.action_space = gym.spaces.Box(-1, 1, (4,), np.float32)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        return self._env.reset(int(seed or 0)), {"is_success": False}

    def step(self, action):
        obs, success, done = self._env.step(np.asarray(action, dtype=np.float64))
        return obs, float(success), success, done, {"is_success": success}


def make_vector_env(task: str, n: int) -> gym.vector.SyncVectorEnv:
    """`n` envs as LeRobot's `make_env` builds them for `lerobot-eval` (autoreset in the same step)."""
    def make() -> gym.Env:
        return gym.wrappers.TimeLimit(MetaWorldCameraGym(task), get_task(task).max_steps)

    return gym.vector.SyncVectorEnv([make] * n, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)

"""A policy with `n_obs_steps` > 1 gets each episode's last observations of every step, reset per
episode (the contract LeRobot's diffusion policies need; docs/contracts.md)."""

import gymnasium as gym
import numpy as np

from goldenticket.noise import Gaussian
from goldenticket.rollout import Episode, rollout
from goldenticket.tasks import get_task


class Clock(gym.Env):
    """Observes {"t": steps taken, "seed": its seed}; ends after 5 + seed % 4 steps."""

    observation_space = gym.spaces.Dict({k: gym.spaces.Box(0, 1e7, (1,)) for k in ("t", "seed")})
    action_space = gym.spaces.Box(-1, 1, (1,))

    def reset(self, seed=None, options=None):
        self.t, self.seed = 0, seed
        return self.obs(), {}

    def step(self, action):
        self.t += 1
        return self.obs(), 0.0, self.t >= 5 + self.seed % 4, False, {"success": False}

    def obs(self):
        return {"t": np.array([self.t], float), "seed": np.array([self.seed], float)}


class Recorder:
    """Remembers, per seed, the observation histories act was given."""

    noise_shape, n_exec, n_obs_steps = (4, 1), 2, 3

    def __init__(self):
        self.seen = {}

    def act(self, obs, noise):
        assert obs["t"].shape == (len(noise), 3, 1)
        for seeds, ts in zip(obs["seed"][:, :, 0], obs["t"][:, :, 0], strict=True):
            self.seen.setdefault(int(seeds[0]), []).append(ts.tolist())
        return np.zeros((len(noise), 2, 1))


def test_each_episode_sees_its_own_last_observations():
    policy = Recorder()
    rollout(policy, get_task(Clock), [Episode(Gaussian(), s) for s in (1_000_000, 1_000_003, 1_000_001)])
    assert policy.seen[1_000_000] == [[0, 0, 0], [0, 1, 2], [2, 3, 4]]  # 5 steps: calls at t = 0, 2, 4
    assert policy.seen[1_000_003] == [[0, 0, 0], [0, 1, 2], [2, 3, 4], [4, 5, 6]]  # 8 steps
    assert policy.seen[1_000_001] == [[0, 0, 0], [0, 1, 2], [2, 3, 4]]  # 6 steps


def test_without_n_obs_steps_act_gets_the_latest_observation():
    class Latest(Recorder):
        n_obs_steps = 1

        def act(self, obs, noise):
            assert obs["t"].shape == (len(noise), 1)
            for seed, t in zip(obs["seed"][:, 0], obs["t"][:, 0], strict=True):
                self.seen.setdefault(int(seed), []).append(t)
            return np.zeros((len(noise), 2, 1))

    policy = Latest()
    rollout(policy, get_task(Clock), [Episode(Gaussian(), 1_000_003)])
    assert policy.seen[1_000_003] == [0, 2, 4, 6]

"""A policy and environments written outside goldenticket, named by import strings in tests."""

import itertools
import multiprocessing as mp
import os

import gymnasium as gym
import numpy as np

from goldenticket.tasks.metaworld import MetaWorldEnv


class PointReach(gym.Env):
    """Move a point to a goal in 2-D; start and goal come from reset's seed; dict observations."""

    box = gym.spaces.Box(-2.0, 2.0, (2,), np.float64)
    observation_space = gym.spaces.Dict({"pos": box, "goal": box})
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float64)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.pos, self.goal = self.np_random.uniform(-1, 1, 2), self.np_random.uniform(-1, 1, 2)
        return self._obs(), {}

    def step(self, action):
        self.pos = np.clip(self.pos + 0.1 * np.clip(action, -1, 1), -2, 2)
        distance = float(np.linalg.norm(self.pos - self.goal))
        return self._obs(), -distance, False, False, {"is_success": distance < 0.05}

    def _obs(self):
        return {"pos": self.pos.copy(), "goal": self.goal.copy()}


class BiasedController:
    """Heads for the goal but aims off target; the injected noise shifts its aim."""

    noise_shape, n_exec, name = (4, 2), 2, "biased-controller"

    def act(self, obs, noise):
        heading = 5 * (obs["goal"] - obs["pos"]) + np.array([0.6, -0.4])
        return np.clip(heading[:, None, :] + noise, -1, 1)[:, : self.n_exec]


class ExactController(BiasedController):
    """Heads straight for the goal: any noise only perturbs it (the zero ticket is best)."""

    name = "exact-controller"

    def act(self, obs, noise):
        heading = 5 * (obs["goal"] - obs["pos"])
        return np.clip(heading[:, None, :] + 2 * noise, -1, 1)[:, : self.n_exec]


class Unseeded(PointReach):
    """Ignores reset's seed: each reset in a process draws the next state of a count (the same states
    in every run), its goal near its start (so the policy's actions answer their noise there)."""

    resets = itertools.count()

    def reset(self, seed=None, options=None):
        super().reset(seed=next(Unseeded.resets))
        self.goal = self.pos + self.np_random.uniform(-0.1, 0.1, 2)
        return self._obs(), {}


class UnseededInPools(PointReach):
    """Ignores reset's seed inside a multiprocessing pool's worker processes only (as an env that
    seeds from a per-process source can), so the single-process checks pass."""

    def reset(self, seed=None, options=None):
        in_pool = mp.current_process().name.startswith("SpawnPoolWorker")
        return super().reset(seed=None if in_pool else seed, options=options)


class SeededPerProcess(PointReach):
    """Seeds reset from its seed and the process id: the same states for a seed in one process, other
    ones in a fresh process."""

    def reset(self, seed=None, options=None):
        return super().reset(seed=seed + os.getpid(), options=options)


class BrokenStep(PointReach):
    def step(self, action):
        raise RuntimeError("the robot fell over")


class BrokenReset(PointReach):
    def reset(self, seed=None, options=None):
        raise RuntimeError("no table in the scene")


class Silent(PointReach):
    def step(self, action):
        obs, reward, terminated, truncated, _ = super().step(action)
        return obs, reward, terminated, truncated, {}


class SeededMetaWorld(gym.Env):
    """The built-in Meta-World reach task behind the plain Gymnasium interface."""

    def __init__(self):
        self.env = MetaWorldEnv("reach-v3")

    def reset(self, seed=None, options=None):
        return self.env.reset(seed), {}

    def step(self, action):
        obs, success, done = self.env.step(action)
        return obs, 0.0, False, done, {"success": success}


class WrongShape(BiasedController):
    def act(self, obs, noise):
        return super().act(obs, noise)[:, 0]


class NaNActions(BiasedController):
    def act(self, obs, noise):
        return super().act(obs, noise) * np.nan


class RareNaN(BiasedController):
    """NaN actions once the point is pushed past x = 1.2, a state few episodes reach (as a real
    network can be non-finite on states it never saw)."""

    def act(self, obs, noise):
        actions = super().act(obs, noise)
        actions[obs["pos"][:, 0] > 1.2] = np.nan
        return actions


class DtypeActions(BiasedController):
    """Actions of another dtype than real numbers."""

    def __init__(self, dtype):
        self.dtype = dtype

    def act(self, obs, noise):
        return super().act(obs, noise).astype(self.dtype)


class RaisingAct(BiasedController):
    def act(self, obs, noise):
        return obs["velocity"]


class IgnoresNoise(BiasedController):
    """Acts as BiasedController does on zero noise, whatever noise it is given."""

    name = "ignores-noise"

    def act(self, obs, noise):
        return super().act(obs, np.zeros_like(noise))


class WideActions(BiasedController):
    """Acts with 3 numbers; PointReach takes 2."""

    noise_shape = (4, 3)

    def act(self, obs, noise):
        return np.clip(noise[:, : self.n_exec], -1, 1)


class BadFingerprint(BiasedController):
    def __init__(self, fingerprint):
        self._fingerprint = fingerprint

    def fingerprint(self):
        return self._fingerprint()


def make_env():
    return PointReach()


def make_policy():
    return BiasedController()


def make_exact_policy():
    return ExactController()


def make_unseeded_env():
    return Unseeded()


def make_silent_env():
    return Silent()


def within_reach(obs, info):
    """A success predicate for Silent, the same rule as PointReach's info["is_success"]."""
    return bool(np.linalg.norm(obs["pos"] - obs["goal"]) < 0.05)


def broken_predicate(obs, info):
    return obs["distance"] < 0.05


def make_unseeded_in_pools_env():
    return UnseededInPools()


def make_per_process_env():
    return SeededPerProcess()


def make_broken_step_env():
    return BrokenStep()


def make_broken_reset_env():
    return BrokenReset()


def make_metaworld_reach():
    return SeededMetaWorld()


def make_metaworld_gym():
    import metaworld  # noqa: F401  (registers Meta-World's own gym ids)

    return gym.make("Meta-World/MT1", env_name="reach-v3")


def make_wrong_shape_policy():
    return WrongShape()


def make_nan_policy():
    return NaNActions()


def make_rare_nan_policy():
    return RareNaN()


def make_complex_policy():
    return DtypeActions(np.complex128)


def make_object_policy():
    return DtypeActions(object)


def make_str_policy():
    return DtypeActions(str)


def make_noise_ignoring_policy():
    return IgnoresNoise()


def make_wide_policy():
    return WideActions()


def make_raising_policy():
    return RaisingAct()


def make_raising_fingerprint_policy():
    return BadFingerprint(lambda: 1 / 0)


def make_int_fingerprint_policy():
    return BadFingerprint(lambda: 42)

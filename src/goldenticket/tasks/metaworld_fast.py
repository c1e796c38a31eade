"""Cheaper, bitwise-identical replacements for the Python Meta-World runs at every step.

A stock pick-place step cost 0.66-0.79 ms in our benchmark runs, of which MuJoCo's physics
(`mj_step`) took ~0.13 ms in a cProfile: the rest is the reward (which we never use), scipy's
matrix-to-quaternion, and array splitting and stacking. `install`
replaces those on one env instance (Meta-World's modules stay as they are) with code that computes
the same floats in the same order; tests/test_metaworld_fast.py steps every replacement beside a
stock env and asks for identical observations and successes.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable

import numpy as np


def install(env, env_name: str) -> None:
    """Put the replacements on one Meta-World env instance."""
    env.touching_object = types.MethodType(touching_object, env)
    env._get_curr_obs_combined_no_goal = types.MethodType(current_observation, env)
    quaternions = type(env)._get_quat_objects
    if "Rotation" in quaternions.__code__.co_names:
        env._get_quat_objects = types.MethodType(_with_global(quaternions, "Rotation", MatrixRotation), env)
    if env_name in SUCCESS and env.reward_function_version == "v2":
        env.evaluate_state = types.MethodType(_success_only(SUCCESS[env_name]), env)


def touching_object(env, object_geom_id: int) -> bool:
    """Meta-World's `SawyerXYZEnv.touching_object` (both gripper pads press on the object) on
    MuJoCo's contact arrays instead of a Python loop over contacts (31% of a profiled pick-place
    step): the same contacts, forces summed in the same order, so the same answer."""
    contacts = env.data.contact
    with_object = (contacts.geom1 == object_geom_id) | (contacts.geom2 == object_geom_id)
    for pad in ("leftpad_geom", "rightpad_geom"):
        pad_id = env.data.geom(pad).id
        touching = with_object & ((contacts.geom1 == pad_id) | (contacts.geom2 == pad_id))
        if not sum(env.data.efc_force[a] for a in contacts.efc_address[touching]) > 0:
            return False
    return True


def current_observation(env) -> np.ndarray:
    """`SawyerXYZEnv._get_curr_obs_combined_no_goal` without its splits and stacks: hand position,
    gripper opening, then each object's position and quaternion, zero-padded to 18 values."""
    gap = np.linalg.norm(env.data.body("rightclaw").xpos - env.data.body("leftclaw").xpos)
    objects = np.concatenate([np.reshape(env._get_pos_objects(), (-1, 3)),
                              np.reshape(env._get_quat_objects(), (-1, 4))], axis=1).ravel()
    obs = np.zeros(4 + env._obs_obj_max_len)
    obs[:3] = env.get_endeff_pos()
    obs[3] = np.clip(gap / 0.1, 0.0, 1.0)
    obs[4:4 + len(objects)] = objects
    return obs


class MatrixRotation:
    """`scipy.spatial.transform.Rotation.from_matrix(m).as_quat()`, the only use Meta-World makes of
    it, as scipy computes it for an orthogonal matrix (the largest of the trace and the diagonal picks
    the formula, then normalise), in plain floats: the same bits, 8 us a call instead of 62. MuJoCo's matrices
    are orthogonal, so scipy's SVD fallback for non-orthogonal input is never taken."""

    def __init__(self, quat: np.ndarray):
        self._quat = quat

    @classmethod
    def from_matrix(cls, matrix: np.ndarray) -> MatrixRotation:
        return cls(quaternion(matrix))

    def as_quat(self) -> np.ndarray:
        return self._quat


def quaternion(matrix: np.ndarray) -> np.ndarray:
    """Scalar-last unit quaternion of a 3x3 rotation matrix, in scipy's order of operations."""
    m = [[float(x) for x in row] for row in np.reshape(matrix, (3, 3))]
    trace = m[0][0] + m[1][1] + m[2][2]
    decision = (m[0][0], m[1][1], m[2][2], trace)
    choice = max(range(4), key=lambda c: (decision[c], -c))  # the first maximum, as argmax
    q = [0.0] * 4
    if choice == 3:
        q = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1], 1 + trace]
    else:
        i = choice
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1 - trace + 2 * m[i][i]
        q[j] = m[j][i] + m[i][j]
        q[k] = m[k][i] + m[i][k]
        q[3] = m[k][j] - m[j][k]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return np.array([x / norm for x in q])


def _with_global(fn: Callable, name: str, value) -> Callable:
    """`fn` with one module-level name rebound, leaving its module as it is."""
    return types.FunctionType(fn.__code__, {**fn.__globals__, name: value}, fn.__name__,
                              fn.__defaults__, fn.__closure__)


def _success_only(success: Callable) -> Callable:
    """An `evaluate_state` that returns only the success flag (the reward is NaN: nothing reads it)."""
    def evaluate_state(env, obs, action):
        return math.nan, {"success": float(success(env, obs))}
    return evaluate_state


def _distance(a, b, scale=1.0) -> float:
    return float(np.linalg.norm((a - b) * scale))


def _window_closed_or_open(env) -> bool:
    """The window tasks' test: the handle's x within TARGET_RADIUS of the goal's."""
    return _distance(env._get_pos_objects()[0], env._target_pos[0]) <= env.TARGET_RADIUS


# Each task's success as its `evaluate_state` computes it (reward version v2), without the reward terms.
SUCCESS: dict[str, Callable] = {
    "button-press-topdown-v3": lambda env, obs: abs(env._target_pos[2] - obs[6]) <= 0.024,
    "door-open-v3": lambda env, obs: abs(obs[4] - env._target_pos[0]) <= 0.08,
    "drawer-close-v3": lambda env, obs: _distance(obs[4:7], env._target_pos) <= env.TARGET_RADIUS + 0.015,
    "drawer-open-v3": lambda env, obs: _distance(obs[4:7], env._target_pos) <= 0.03,
    "peg-insert-side-v3": lambda env, obs: _distance(env._get_site_pos("pegHead"), env._target_pos,
                                                     scale=np.array([1.0, 2.0, 2.0])) <= 0.07,
    "pick-place-v3": lambda env, obs: _distance(obs[4:7], env._target_pos) <= 0.07,
    "push-v3": lambda env, obs: _distance(obs[4:7], env._target_pos) <= env.TARGET_RADIUS,
    "reach-v3": lambda env, obs: _distance(env.tcp_center, env._target_pos) <= 0.05,
    "window-close-v3": lambda env, obs: _window_closed_or_open(env),
    "window-open-v3": lambda env, obs: _window_closed_or_open(env),
}

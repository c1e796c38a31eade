"""Scripted experts for robomimic's Lift and Can (`goldenticket train` demonstrations).

Each reads the simulator's state (the object's position, Can's target bin) and steers the Panda's
hand through waypoints with the pose controller's delta inputs: above the object, down, close the
gripper, up, and for Can over its bin, then open. A demonstrator's habit shifts where it grasps
(the object seen shifted in x, y) and where it places (the bin target shifted); the same expert
without habits succeeds on 10 of 10 Lift and 10 of 10 Can seeds (tests/test_robomimic.py).
"""

from __future__ import annotations

import numpy as np

from goldenticket.errors import UserError

HOVER = 0.08  # m above the object before descending
GRASP_DEPTH = -0.005  # m from the object's centre where the hand closes
CARRY_HEIGHT = 1.05  # m (world z) at which Can is carried over the bin walls
CLOSE_STEPS = 8
DESCEND_STEPS = 25  # a descent blocked above the object closes the gripper anyway
STEP = 0.05  # m a pose-controller input of 1 moves the hand (OSC_POSE's output_max)


class PickExpert:
    """One episode's expert for Lift (`place=False`: pick and lift) or Can (`place=True`: into its bin)."""

    def __init__(self, env, place: bool, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        self.sim, self.place = env.robosuite_env, place
        self.grasp_shift, self.goal_shift = grasp_shift, goal_shift
        self.phase, self.timer = "above", 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The action for observation `obs` (the hand's position is its first three numbers)."""
        hand, target = obs[:3], self._object()
        target += [*self.grasp_shift, GRASP_DEPTH]
        close = self.phase in ("close", "up", "carry")
        if self.phase == "above":
            target = target + [0, 0, HOVER]
            self._next_if(np.linalg.norm((hand - target)[:2]) < 0.01, "down")
        elif self.phase == "down":
            self.timer += 1
            self._next_if(abs(hand[2] - target[2]) < 0.01 or self.timer > DESCEND_STEPS, "close")
        elif self.phase == "close":
            self.timer += 1
            self._next_if(self.timer > CLOSE_STEPS, "up")
        elif self.phase == "up":
            target = np.r_[hand[:2], CARRY_HEIGHT if self.place else target[2] + 0.25]
            self._next_if(self.place and hand[2] > CARRY_HEIGHT - 0.02, "carry")
        elif self.phase == "carry":
            target = np.r_[self._goal()[:2] + self.goal_shift, CARRY_HEIGHT]
            self._next_if(np.linalg.norm((hand - target)[:2]) < 0.02, "open")
        else:  # open: let go where it is
            target = hand
        action = np.zeros(7)
        action[:3] = np.clip((target - hand) / STEP, -1, 1)
        action[6] = 1.0 if close else -1.0
        return action

    def _next_if(self, done: bool, phase: str) -> None:
        if done:
            self.phase, self.timer = phase, 0

    def _object(self) -> np.ndarray:
        body = self.sim.obj_body_id["Can"] if self.place else self.sim.cube_body_id
        return self.sim.sim.data.body_xpos[body].copy()

    def _goal(self) -> np.ndarray:
        return np.asarray(self.sim.target_bin_placements[self.sim.object_to_id["can"]])


EXPERTS = {"robomimic/lift": False, "robomimic/can": True}  # task -> place


def check(task: str) -> None:
    """UserError for a robomimic task without a scripted expert."""
    if task not in EXPERTS:
        raise UserError(f"no scripted expert for {task}; robomimic's are for {', '.join(EXPERTS)}")


def expert(task: str, env, grasp_shift: np.ndarray, goal_shift: np.ndarray) -> PickExpert:
    """The scripted expert of a robomimic task (`check`ed) for one episode."""
    return PickExpert(env, EXPERTS[task], grasp_shift, goal_shift)

"""Scripted experts for robomimic's Lift, Can and Square (`goldenticket train` demonstrations).

Each reads the simulator's state (the object's pose, Can's target bin, Square's peg) and steers the
Panda's hand through waypoints with the pose controller's delta inputs: above the object, down,
close the gripper, up, and for Can over its bin, then open. Square's expert first turns the hand
across the nut's handle, and carries the nut over its peg turned square to it before lowering it
down the peg and letting go. A demonstrator's habit shifts where it grasps (the object or handle
seen shifted in x, y) and where it places (the bin or peg seen shifted); without habits each expert
succeeds on 10 of 10 seeds (tests/test_robomimic.py).
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
YAW_STEP = 0.087  # rad a yaw input of 1 turns the hand (measured)
# Square: the grasp sits this far out along the handle from its centre, clear of the nut's ring; the
# nut is carried above its peg's top (0.95 m) and lowered once within 4 mm and 3 degrees of square
HANDLE_OUT = 0.01
NUT_CARRY_HEIGHT = 1.03
NUT_ALIGNED = (0.004, 0.05)  # m, rad
NUT_DOWN = 0.86  # m (world z) of the nut's centre below which it is down its peg
LOWER_STEPS, OPEN_STEPS = 60, 6


class Waypoints:
    """One episode's phases, and the pose-controller action towards a target."""

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        self.sim = env.robosuite_env
        self.grasp_shift, self.goal_shift = grasp_shift, goal_shift
        self.phase, self.timer = "above", 0

    def _next_if(self, done: bool, phase: str) -> None:
        if done:
            self.phase, self.timer = phase, 0

    @staticmethod
    def _action(hand: np.ndarray, target: np.ndarray, close: bool, yaw_error: float = 0.0) -> np.ndarray:
        action = np.zeros(7)
        action[:3] = np.clip((target - hand) / STEP, -1, 1)
        action[5] = np.clip(yaw_error / YAW_STEP, -1, 1)
        action[6] = 1.0 if close else -1.0
        return action


class PickExpert(Waypoints):
    """Lift's (`place=False`: pick and lift) or Can's (`place=True`: into its bin) expert."""

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray, place: bool):
        super().__init__(env, grasp_shift, goal_shift)
        self.place = place

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
        return self._action(hand, target, close)

    def _object(self) -> np.ndarray:
        body = self.sim.obj_body_id["Can"] if self.place else self.sim.cube_body_id
        return self.sim.sim.data.body_xpos[body].copy()

    def _goal(self) -> np.ndarray:
        return np.asarray(self.sim.target_bin_placements[self.sim.object_to_id["can"]])


class NutExpert(Waypoints):
    """Square's expert: the square nut by its handle onto the square peg."""

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        super().__init__(env, grasp_shift, goal_shift)
        model, data = self.sim.sim.model, self.sim.sim.data
        self.nut = self.sim.obj_body_id["SquareNut"]
        self.handle = model.site_name2id(self.sim.nuts[0].important_sites["handle"])
        self.fingers = [model.body_name2id(f"gripper0_right_{side}finger") for side in ("left", "right")]
        self.peg = data.body_xpos[self.sim.peg1_body_id][:2].copy()

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The action for observation `obs` (the hand's position is its first three numbers)."""
        data, hand = self.sim.sim.data, obs[:3]
        nut, handle = data.body_xpos[self.nut].copy(), data.site_xpos[self.handle].copy()
        outward = (handle - nut)[:2] / np.linalg.norm((handle - nut)[:2])
        grasp = handle + [*(self.grasp_shift + HANDLE_OUT * outward), 0]
        across = wrapped(np.arctan2(outward[1], outward[0]) + np.pi / 2 - self._finger_angle(), np.pi)
        goal = self.peg + self.goal_shift
        square = wrapped(-self._nut_yaw(), np.pi / 2)
        if self.phase == "above":
            target, yaw_error = grasp + [0, 0, HOVER], across
            self._next_if(np.linalg.norm((hand - target)[:2]) < 0.005 and abs(across) < 0.03, "down")
        elif self.phase == "down":
            target, yaw_error = grasp, across
            self.timer += 1
            self._next_if(abs(hand[2] - target[2]) < 0.005 or self.timer > DESCEND_STEPS, "close")
        elif self.phase in ("close", "open"):
            target, yaw_error = hand, 0.0
            self.timer += 1
            self._next_if(self.timer > (CLOSE_STEPS if self.phase == "close" else OPEN_STEPS),
                          "up" if self.phase == "close" else "leave")
        elif self.phase == "up":
            target, yaw_error = np.r_[hand[:2], NUT_CARRY_HEIGHT], 0.0
            self._next_if(hand[2] > NUT_CARRY_HEIGHT - 0.02, "carry")
        elif self.phase in ("carry", "lower"):
            target, yaw_error = np.r_[hand[:2] + goal - nut[:2], NUT_CARRY_HEIGHT], square
            if self.phase == "carry":
                over_peg = np.linalg.norm(goal - nut[:2]) < NUT_ALIGNED[0] and abs(square) < NUT_ALIGNED[1]
                self._next_if(over_peg, "lower")
            else:
                target[2], self.timer = hand[2] - 0.02, self.timer + 1
                self._next_if(nut[2] < NUT_DOWN or self.timer > LOWER_STEPS, "open")
        else:  # leave: up and away from the nut
            target, yaw_error = hand + [0, 0, 0.05], 0.0
        return self._action(hand, target, self.phase in ("close", "up", "carry", "lower"), yaw_error)

    def _finger_angle(self) -> float:
        """The direction the gripper's fingers close along, in the table's plane."""
        left, right = (self.sim.sim.data.body_xpos[body] for body in self.fingers)
        return float(np.arctan2(*(left - right)[1::-1]))

    def _nut_yaw(self) -> float:
        rotation = self.sim.sim.data.body_xmat[self.nut].reshape(3, 3)
        return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


def wrapped(angle: float, period: float) -> float:
    """`angle` shifted by whole periods into [-period / 2, period / 2)."""
    return (angle + period / 2) % period - period / 2


EXPERTS = {"robomimic/lift": lambda env, grasp, goal: PickExpert(env, grasp, goal, place=False),
           "robomimic/can": lambda env, grasp, goal: PickExpert(env, grasp, goal, place=True),
           "robomimic/square": NutExpert}


def check(task: str) -> None:
    """UserError for a robomimic task without a scripted expert."""
    if task not in EXPERTS:
        raise UserError(f"no scripted expert for {task}; robomimic's are for {', '.join(EXPERTS)}")


def expert(task: str, env, grasp_shift: np.ndarray, goal_shift: np.ndarray) -> Waypoints:
    """The scripted expert of a robomimic task (`check`ed) for one episode."""
    return EXPERTS[task](env, grasp_shift, goal_shift)

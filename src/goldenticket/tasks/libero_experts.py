"""A scripted expert for LIBERO-Object's tasks (`libero/object/<id>`, `libero-listed/object/<id>`):
pick up the object the task names and place it in the basket.

It reads the simulator's state (the object the BDDL goal puts `In` the basket's region, the region,
every object's extent) and steers the Panda's hand, pointing down, through waypoints with the pose
controller's delta inputs (LIBERO's relative control mode): over the object at a height clear of the
scene, turned and slid along the object so that its palm and fingers miss the neighbours; down until
the fingers straddle the object's top (or its sides, for a flat box); close; up until the object's
bottom clears the basket's rim (grasping again if the object stayed behind or fell); over the
basket's region; down into it; open. A demonstrator's habit shifts where it grasps (the object seen
shifted in x, y) and where it places (the region seen shifted); `train.collect_demos` adds the
action noise. It draws no random numbers: a seed and a habit give one episode.

Measured by `benchmarks/libero_expert.py` (benchmarks/results/libero_expert.md): success per task
without habits and with grasp and goal shifts and action noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goldenticket.errors import UserError
from goldenticket.tasks.robomimic_experts import Waypoints, wrapped

SUITE_TASKS = 10  # LIBERO-Object's task ids: 0 to 9
CLEARANCE = 0.05  # m between the lowest fingertip and any object's top while travelling
GRASP_BELOW_TOP = 0.03  # m below the object's top where the hand's site closes
FLOOR_GAP = 0.015  # m above the object's bottom the hand's site stays (a flat box is held by its sides)
FINGER_GAP = 0.07  # m: the widest object across the open fingers
SLIDES = 5  # grasp points tried along the object, across the fingers
PAD = 0.009  # m: half a finger pad's width
# The hand around its site, (half length along the finger axis, half width across it, reach below the
# site): the palm, and the fingers (m)
PALM = (0.106, 0.04, -0.024)
FINGERS = (0.068, 0.014, 0.013)
MARGIN = 0.005  # m kept between the hand and a neighbour
HOLD = 0.01  # m below the object's top the hand's site must reach to hold it
RIM_CLEARANCE = 0.03  # m above the basket's rim the carried object's bottom travels
RELEASE_HEIGHT = 0.03  # m above the region's bottom where the object's bottom is let go
LIFTED = 0.01  # m the object's bottom rises once held (checked once the hand is LIFT_CHECK up)
LIFT_CHECK = 0.05
CLOSE_STEPS, OPEN_STEPS = 10, 8
DESCEND_STEPS, LOWER_STEPS = 30, 40  # a descent blocked on the way closes or opens the gripper anyway


@dataclass(frozen=True)
class Grasp:
    centre: np.ndarray  # x, y of the hand's site
    height: float  # of the hand's site when it closes
    angle: float  # the fingers' axis in the table's plane (rad, mod pi)


class BasketExpert(Waypoints):
    """LIBERO-Object's expert: the task's object into the basket's region."""

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        super().__init__(env, grasp_shift, goal_shift)
        self.grasp: Grasp | None = None  # planned from the scene as "above" begins
        self.held_at = np.zeros(2)  # the hand's height and the object's bottom when the gripper closed

    def act(self, obs: dict) -> np.ndarray:
        """The action for observation `obs`, read from the simulator's state."""
        hand = self._hand()
        thing, region = self._goal_names()
        low, high = self._extent(thing)
        if self._dropped(hand, low):  # grasp again
            self.grasp, self.phase, self.timer = None, "above", 0
        grasp = self.grasp = self.grasp or self._plan(thing)
        yaw_error = wrapped(grasp.angle - self._finger_angle(), np.pi)
        if self.phase == "above":
            target = np.r_[grasp.centre, self._travel_height()]
            self._next_if(np.linalg.norm((hand - target)[:2]) < 0.005 and abs(yaw_error) < 0.05, "down")
        elif self.phase == "down":
            aligned = np.linalg.norm(hand[:2] - grasp.centre) < 0.01
            target, self.timer = np.r_[grasp.centre, grasp.height if aligned else hand[2]], self.timer + 1
            self._next_if(abs(hand[2] - grasp.height) < 0.005 or self.timer > DESCEND_STEPS, "close")
        elif self.phase in ("close", "open"):
            target, self.timer = hand, self.timer + 1
            if self.phase == "close":
                self.held_at = np.r_[hand[2], low[2]]
            self._next_if(self.timer > (CLOSE_STEPS if self.phase == "close" else OPEN_STEPS),
                          "up" if self.phase == "close" else "leave")
        elif self.phase == "up":
            target = np.r_[hand[:2], self._carry_height()]
            self._next_if(hand[2] > target[2] - 0.01, "carry")
        elif self.phase in ("carry", "lower"):
            centre, bottom = self._region(region)
            target = np.r_[hand[:2] + centre + self.goal_shift - (low + high)[:2] / 2, self._carry_height()]
            if self.phase == "carry":
                self._next_if(np.linalg.norm((hand - target)[:2]) < 0.01, "lower")
            else:
                target[2], self.timer = hand[2] - low[2] + bottom + RELEASE_HEIGHT, self.timer + 1
                self._next_if(abs(hand[2] - target[2]) < 0.01 or self.timer > LOWER_STEPS, "open")
        else:  # leave: straight up
            target = hand + [0, 0, 0.05]
        return self._action(hand, target, self.phase in ("close", "up", "carry", "lower"), yaw_error)

    def _plan(self, thing: str) -> Grasp:
        """Where the hand closes on the object: turned so that its fingers fit across the object, and
        slid along the object, so that it can go lowest between the neighbours (of equals, the least
        slid, fingers along y as the hand starts before along x)."""
        low, high = self._extent(thing)
        neighbours = [self._extent(name) for name in self.sim.obj_body_id if name != thing]
        fitting = [axis for axis in (1, 0) if high[axis] - low[axis] < FINGER_GAP] or [1]
        lowest = max(high[2] - GRASP_BELOW_TOP, low[2] + FLOOR_GAP)
        options = []
        for axis in fitting:
            room = max((high - low)[1 - axis] / 2 - PAD, 0.0)  # for the finger pads along the object
            for slide in sorted(np.linspace(-room, room, SLIDES), key=abs):
                centre = (low + high)[:2] / 2 + self.grasp_shift + np.where(np.arange(2) == axis, 0.0, slide)
                options.append(Grasp(centre, max([lowest, *clear_heights(centre, axis, neighbours)]),
                                     np.pi / 2 if axis == 1 else 0.0))
        best = min(options, key=lambda grasp: grasp.height)
        if best.height > max(lowest, high[2] - HOLD):  # no way down clear of the neighbours: among them
            return Grasp(options[0].centre, lowest, options[0].angle)
        return best

    def _dropped(self, hand: np.ndarray, low: np.ndarray) -> bool:
        """Whether the object stayed on the table as the hand rose, or fell from it on the way."""
        lifting = self.phase == "carry" or self.phase == "up" and hand[2] > self.held_at[0] + LIFT_CHECK
        return lifting and low[2] < self.held_at[1] + LIFTED

    def _carry_height(self) -> float:
        """The hand's height with the held object's bottom clear above the basket's rim."""
        return self.held_at[0] - self.held_at[1] + self._rim() + RIM_CLEARANCE

    def _hand(self) -> np.ndarray:
        return self.sim.sim.data.site_xpos[self.sim.robots[0].eef_site_id].copy()

    def _finger_angle(self) -> float:
        """The direction the fingers close along, in the table's plane."""
        data, model, pads = self.sim.sim.data, self.sim.sim.model, self.sim.robots[0].gripper.important_geoms
        left, right = (data.geom_xpos[model.geom_name2id(pads[f"{side}_fingerpad"][0])]
                       for side in ("left", "right"))
        return float(np.arctan2(*(left - right)[1::-1]))

    def _goal_names(self) -> tuple[str, str]:
        """(the object, the region) of the task's goal `(In object region)`."""
        (_, thing, region), = self.sim.parsed_problem["goal_state"]
        return thing, region

    def _extent(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """The world-aligned box around the object's collision geoms: (lowest corner, highest corner)."""
        model, data = self.sim.sim.model, self.sim.sim.data
        geoms = np.flatnonzero((model.body_rootid[model.geom_bodyid] == self.sim.obj_body_id[name])
                               & (model.geom_contype | model.geom_conaffinity).astype(bool))
        rotations = data.geom_xmat[geoms].reshape(-1, 3, 3)
        centres = data.geom_xpos[geoms] + np.einsum("gij,gj->gi", rotations, model.geom_aabb[geoms, :3])
        halves = np.einsum("gij,gj->gi", np.abs(rotations), model.geom_aabb[geoms, 3:])
        return (centres - halves).min(axis=0), (centres + halves).max(axis=0)

    def _travel_height(self) -> float:
        """The hand's height with its fingertips clear above every object."""
        return max(self._extent(name)[1][2] for name in self.sim.obj_body_id) + CLEARANCE + FINGERS[2]

    def _rim(self) -> float:
        """The top of the basket (the object the goal's region belongs to)."""
        return self._extent(self._goal_names()[1].removesuffix("_contain_region"))[1][2]

    def _region(self, name: str) -> tuple[np.ndarray, float]:
        """The goal region's centre in x, y and its bottom's height."""
        data, size = self.sim.sim.data, self.sim.object_sites_dict[name].size
        centre = data.get_site_xpos(name)
        half = np.abs(data.get_site_xmat(name).reshape(3, 3) @ size)
        return centre[:2].copy(), centre[2] - half[2]


def clear_heights(centre: np.ndarray, axis: int, boxes: list) -> list[float]:
    """The hand's lowest heights over `centre`, its fingers along `axis`, for the boxes (low, high)
    under its palm or fingers to stay clear below them."""
    return [high[2] + reach + MARGIN for low, high in boxes for along, across, reach in (PALM, FINGERS)
            if overlaps(centre, axis, along, across, low, high)]


def overlaps(centre: np.ndarray, axis: int, along: float, across: float, low: np.ndarray,
             high: np.ndarray) -> bool:
    """Whether a box (low, high) meets, in x and y, the rectangle about `centre` reaching `along` on
    `axis` (0: x, 1: y) and `across` on the other, widened by MARGIN."""
    reach = np.where(np.arange(2) == axis, along, across) + MARGIN
    return bool(np.all(low[:2] < centre + reach) and np.all(high[:2] > centre - reach))


def check(task: str) -> None:
    """UserError for a task without a LIBERO scripted expert."""
    parts = task.split("/")
    if not (len(parts) == 3 and parts[0] in ("libero", "libero-listed") and parts[1] == "object"
            and parts[2].isdigit() and int(parts[2]) < SUITE_TASKS):
        raise UserError(f"no scripted expert for {task}; LIBERO's is for LIBERO-Object's tasks, "
                        f"libero/object/0 to {SUITE_TASKS - 1} (or libero-listed/object/...)")


def expert(task: str, env, grasp_shift: np.ndarray, goal_shift: np.ndarray) -> BasketExpert:
    """The scripted expert of a LIBERO-Object task (`check`ed) for one episode."""
    return BasketExpert(env, grasp_shift, goal_shift)

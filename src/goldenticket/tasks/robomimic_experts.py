"""Scripted experts for robomimic's Lift, Can, Square and Transport (`goldenticket train` demonstrations).

Each reads the simulator's state (the object's pose, Can's target bin, Square's peg, Transport's
lid, payload, trash and bins) and steers the Panda's hand through waypoints with the pose
controller's delta inputs: above the object, down, close the gripper, up, and for Can over its bin,
then open. Square's expert first turns the hand across the nut's handle, and carries the nut over
its peg turned square to it before lowering it down the peg and letting go. Transport's moves both
arms at once, as neither reaches both tables: arm 0 lifts the lid off the start bin and sets it down
beside it, then picks the payload (a hammer) out of the start bin by its handle and holds it out
over the gap between the tables; arm 1 meanwhile puts the trash from the target bin into the trash
bin, then takes the payload by its handle's other part, arm 0 lets go, and arm 1 lowers it into the
target bin. A demonstrator's habit shifts where it grasps (the object or handle seen shifted in x,
y; Transport's lid, trash and payload in their bins, not the payload in arm 0's hand) and where it
places (the bin or peg seen shifted: Transport's trash and target bins); without habits each expert
succeeds on 10 of 10 training seeds (tests/test_robomimic.py; Transport's, about 8 s an episode,
on two there).
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
# Transport: heights are world z (m); the gap between the tables is at y = 0, between the arms' bases
ARM_OBS = 9  # observation numbers an arm: its hand's position, quaternion and fingers
RIM = 0.99  # the hand's height with its fingertips clear above a bin's walls
LID_PLACE = np.array([-0.2, -0.45])  # x, y where arm 0 sets the lid down, beside the start bin
# x, y where arm 1 takes the payload, near both arms' reach; each demonstrator moves it along x by
# its goal shift's x, so that a policy learns to find the handle wherever arm 0 holds it out
HANDOVER = np.array([0.0, 0.055])
HANDOVER_HEIGHT = 1.0  # of arm 0's hand holding the payload out
ARRIVING = 0.1  # m from the handover within which arm 0 lowers the payload, clear of the start bin
WAIT_BACK = 0.15  # m (y) behind the handover arm 1 waits
# m from the handover within which arm 0 has brought arm 1's grasp point when arm 1 comes in for
# the payload: well before arm 0 stops, so that a policy's arm 1 comes in wherever its arm 0 halts
COME_IN = 0.12
HIGH_CARRY = CARRY_HEIGHT + 0.05  # arm 1 carries the payload, held off its centre of mass, this high
# m from the payload handle's centre where arm 0 holds it: near the head (past the payload's centre
# of mass, 0.06 m towards the head) when the head lies towards arm 0, else on the handle's other
# half; arm 1 holds it HANDS_APART on, towards itself, so that each hand reaches the handover
HEAD_GRASP, BUTT_GRASP = 0.07, 0.04
HANDS_APART = HEAD_GRASP + BUTT_GRASP
HANDLE_REACH = 0.09  # m from the handle's centre a hand may hold it (the handle is 0.2 m long)
PALM = (0.106, 0.04)  # m: the Panda palm's half length along the finger axis and its half width
BIN_INSIDE, WALL_MARGIN = 0.14, 0.005  # m from a bin's centre to its walls' inner faces; kept clear
GRASP_ABOVE = 0.005  # m above a thing's centre where the hand closes: the fingertips clear the floor
GRASP_TOLERANCE = 0.005  # m in height
REACHED, TURNED = 0.01, 0.05  # m, rad: near enough a waypoint, and the fingers' angle
VERTICAL_STEP = 0.025  # m a step's target lies above or below the hand (faster swings the arm aside)
SETTLED = 0.003  # m the hand moves in a step at rest
SETTLE_STEPS = 40  # a descent not at rest at its grasp by then (blocked) closes the gripper anyway
PAYLOAD_STEP = 0.03  # m a step's target lies from a hand carrying the payload (held off its centre)
HELD = 0.1  # m below the hand within which a held thing stays
LEAVE, LEAVE_STEPS = 0.05, 15  # m arm 0's open hand rises off the payload's handle, within steps
RETREAT = -0.3  # m (y) to which arm 0 then draws back
WRIST = 2.8  # rad: turns keep the wrist joint within this (its limits are 2.9)


class Waypoints:
    """One episode's phases, and the pose-controller action towards a target."""

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        self.sim = env.robosuite_env
        self.grasp_shift, self.goal_shift = grasp_shift, goal_shift
        self.phase, self.timer = "above", 0

    def _next_if(self, done: bool, phase: str) -> None:
        if done:
            self.phase, self.timer = phase, 0

    def _finger_angle(self) -> float:
        """The direction the gripper's fingers (bodies `self.fingers`) close along, in the table's plane."""
        left, right = (self.sim.sim.data.body_xpos[body] for body in self.fingers)
        return float(np.arctan2(*(left - right)[1::-1]))

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
        self.fingers = finger_bodies(model, arm=0)
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

    def _nut_yaw(self) -> float:
        rotation = self.sim.sim.data.body_xmat[self.nut].reshape(3, 3)
        return float(np.arctan2(rotation[1, 0], rotation[0, 0]))


class TransportArm(Waypoints):
    """One of Transport's arms: its phases, "<thing> <step>" in order, each step a method giving the
    hand's target, the yaw turning its fingers and whether the gripper closes. The hand is kept
    pointing down (zero rotation inputs would let it tilt)."""

    arm: int
    phases: tuple[str, ...]
    partner_done: str  # the other arm's phase that ends this arm's hold

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        super().__init__(env, grasp_shift, goal_shift)
        model, robot = self.sim.sim.model, self.sim.robots[self.arm]
        self.transport, self.partner = self.sim.transport, None
        self.phase, self.anchor, self.hand, self.speed = self.phases[0], None, None, 0.0
        self.fingers = finger_bodies(model, self.arm)
        self.hands = [each.eef_site_id["right"] for each in self.sim.robots]
        self.wrist = model.jnt_qposadr[model.joint_name2id(robot.robot_model.naming_prefix + "joint7")]
        self.lid = model.geom_name2id(self.transport.lid.handle_geoms[0])
        self.start_bin = model.body_name2id(self.transport.start_bin.root_body)

    def act(self, hand: np.ndarray) -> np.ndarray:
        """This arm's 7 actions, its hand at `hand`."""
        if self.anchor is None:
            self.anchor = self.hand = hand.copy()
        self.speed, self.hand = float(np.linalg.norm(hand - self.hand)), hand.copy()
        thing, step = self.phase.split()
        target, yaw_error, close = getattr(self, f"_{step}")(hand, thing)
        action = self._action(hand, target, close, yaw_error)
        pointing = self.sim.sim.data.site_xmat[self.hands[self.arm]].reshape(3, 3)[:, 2]
        action[3:6] += np.clip(np.cross(pointing, [0, 0, -1.0]) / YAW_STEP, -1, 1)
        return action

    def _go(self, phase: str) -> None:
        """On to `phase`, anchored where the hand is."""
        self.phase, self.timer, self.anchor = phase, 0, self.hand.copy()

    def _advance(self, done: bool) -> None:
        """On to the next phase once `done` (the last one lasts)."""
        if done and self.phase != self.phases[-1]:
            self._go(self.phases[self.phases.index(self.phase) + 1])

    def _position(self, thing: str) -> np.ndarray:
        """Where the lid's handle, the trash or the payload's handle centre is."""
        if thing == "lid":
            return self.sim.sim.data.geom_xpos[self.lid].copy()
        return self.transport.trash_pos if thing == "trash" else self.transport.payload_pos

    def _grasp(self, thing: str) -> tuple[np.ndarray, float]:
        """Where the hand closes on `thing`, and the yaw turning its fingers across it."""
        data = self.sim.sim.data
        if thing == "payload":  # arm 1 takes it where arm 0's hand holds it out: no habit
            shift = self.grasp_shift if self.arm == 0 else np.zeros(2)
            across = self._turn(heading(self._head()) + np.pi / 2, np.pi)
            return self._handle_point(self.arm) + [*shift, GRASP_ABOVE], across
        frame = data.geom_xmat[self.lid] if thing == "lid" else data.body_xmat[self.transport.trash_body_id]
        period = np.pi if thing == "lid" else np.pi / 2  # across the lid's handle, square to the cube
        across = self._turn(heading(frame.reshape(3, 3)[:, 0]), period)
        return self._position(thing) + [*self.grasp_shift, GRASP_ABOVE], across

    def _head(self) -> np.ndarray:
        """The unit vector along the payload's handle towards its head."""
        return self.sim.sim.data.body_xmat[self.transport.payload_body_id].reshape(3, 3)[:, 2].copy()

    def _handle_point(self, arm: int) -> np.ndarray:
        """Where on the payload's handle `arm` holds it. Arm 0 picks it from the start bin by the
        handle's half nearer arm 0 (HEAD_GRASP, BUTT_GRASP), its palm clear of the bin's walls; arm 1
        takes it HANDS_APART further towards itself than arm 0's hand."""
        centre, head = self.transport.payload_pos, self._head()
        towards_arm1 = head if head[1] >= 0 else -head
        if arm == 1:
            held = (self.sim.sim.data.site_xpos[self.hands[0]] - centre) @ towards_arm1
            return centre + towards_arm1 * min(held + HANDS_APART, HANDLE_REACH)
        seen = centre[:2] + self.grasp_shift - self.sim.sim.data.body_xpos[self.start_bin][:2]
        along = -BUTT_GRASP if head[1] >= 0 else -HEAD_GRASP
        return centre + towards_arm1 * slide_into_bin(seen, towards_arm1[:2], along)

    def _turn(self, fingers_along: float, period: float) -> float:
        """The shortest yaw turning the fingers along `fingers_along` (mod `period`) that keeps the wrist
        joint within WRIST (a yaw of the hand, pointing down, turns that joint back)."""
        turns = wrapped(fingers_along - self._finger_angle(), period) + period * np.arange(-2, 3)
        fits = turns[np.abs(self.sim.sim.data.qpos[self.wrist] - turns) < WRIST]
        return float(min(fits, key=abs)) if len(fits) else float(turns[2])

    def _holding(self, hand: np.ndarray, thing: str) -> bool:
        return bool(self._position(thing)[2] > hand[2] - HELD)

    def _above(self, hand, thing):
        point, yaw_error = self._grasp(thing)
        target = np.r_[point[:2], max(RIM, point[2] + HOVER)]
        self._advance(np.linalg.norm((hand - target)[:2]) < REACHED and abs(yaw_error) < TURNED)
        return target, yaw_error, False

    def _down(self, hand, thing):
        """Down to the grasp, slowly, until the hand rests there (or is blocked on the way)."""
        point, yaw_error = self._grasp(thing)
        self.timer += 1
        there = abs(hand[2] - point[2]) < GRASP_TOLERANCE and np.linalg.norm((hand - point)[:2]) < REACHED
        self._advance((there and self.speed < SETTLED) or self.timer > SETTLE_STEPS)
        return np.r_[point[:2], max(point[2], hand[2] - VERTICAL_STEP)], yaw_error, False

    def _close(self, hand, thing):
        self.timer += 1
        self._advance(self.timer > CLOSE_STEPS)
        return self.anchor, 0.0, True

    def _open(self, hand, thing):
        self.timer += 1
        self._advance(self.timer > OPEN_STEPS)
        return self.anchor, 0.0, False

    def _up(self, hand, thing):
        """Up to the carrying height, slowly; then on, or back to grasp again if `thing` stayed behind."""
        height = self._carry_height(thing)
        if hand[2] > height - 0.02:
            if self._holding(hand, thing):
                self._advance(True)
            else:
                self._go(f"{thing} above")
        return np.r_[self.anchor[:2], min(height, hand[2] + VERTICAL_STEP)], 0.0, True

    def _carry(self, hand, thing):
        """Towards the arm's goal for `thing`; back to grasp again if it dropped."""
        if not self._holding(hand, thing):
            self._go(f"{thing} above")
            return hand, 0.0, False
        target, yaw_error, done = self._goal(hand, thing)
        self._advance(done)
        if thing == "payload":  # slowly: a hand holds it off its centre of mass
            target = towards(hand, target, PAYLOAD_STEP)
        return target, yaw_error, True

    def _hold(self, hand, thing):
        self._advance(self.partner.phase == self.partner_done)
        return self.anchor, 0.0, True

    def _carry_height(self, thing: str) -> float:
        return CARRY_HEIGHT

    def _handover(self) -> np.ndarray:
        """Where, in x and y, arm 1 takes the payload from arm 0: HANDOVER, shifted by the goal shift."""
        return HANDOVER + [self.goal_shift[0], 0.0]

    def _goal(self, hand: np.ndarray, thing: str) -> tuple[np.ndarray, float, bool]:
        """The hand's target carrying `thing`, the fingers' yaw, and whether it has arrived."""
        raise NotImplementedError


class LidArm(TransportArm):
    """Transport's arm 0: the lid off the start bin and down beside it; then the payload out of the
    start bin, held out over the gap between the tables until arm 1 has it."""

    arm = 0
    phases = ("lid above", "lid down", "lid close", "lid up", "lid carry", "lid open",
              "payload above", "payload down", "payload close", "payload up", "payload carry",
              "payload hold", "payload open", "payload leave", "payload retreat")
    partner_done = "payload hold"

    def _goal(self, hand, thing):
        if thing == "lid":
            target = np.r_[LID_PLACE, CARRY_HEIGHT]
            return target, 0.0, np.linalg.norm(target - hand) < REACHED
        target = hand[:2] + self._handover() - self._handle_point(1)[:2]
        arriving = np.linalg.norm(target - hand[:2]) < ARRIVING  # clear of the start bin's walls
        target = np.r_[target, HANDOVER_HEIGHT if arriving else CARRY_HEIGHT]
        along_y = self._turn(self._finger_angle() + np.pi / 2 - heading(self._head()), np.pi)
        return target, along_y, np.linalg.norm(target - hand) < REACHED and abs(along_y) < TURNED

    def _leave(self, hand, thing):
        """The open hand up off the payload's handle."""
        target = self.anchor + [0, 0, LEAVE]
        self.timer += 1
        self._advance(hand[2] > target[2] - 0.01 or self.timer > LEAVE_STEPS)
        return target, 0.0, False

    def _retreat(self, hand, thing):
        return np.r_[self.anchor[0], RETREAT, self.anchor[2]], 0.0, False


class TrashArm(TransportArm):
    """Transport's arm 1: the trash out of the target bin into the trash bin; then the payload from
    arm 0's hand into the target bin."""

    arm = 1
    phases = ("trash above", "trash down", "trash close", "trash up", "trash carry", "trash open",
              "payload wait", "payload above", "payload down", "payload close", "payload hold",
              "payload up", "payload carry", "payload lower", "payload open")
    partner_done = "payload retreat"

    def _carry_height(self, thing):
        return CARRY_HEIGHT if thing == "trash" else HIGH_CARRY

    def _goal(self, hand, thing):
        bin_ = self.transport.trash_bin_pos if thing == "trash" else self.transport.target_bin_pos
        goal, held = bin_[:2] + self.goal_shift, self._position(thing)
        target = np.r_[hand[:2] + goal - held[:2], self._carry_height(thing)]
        return target, 0.0, np.linalg.norm(goal - held[:2]) < REACHED

    def _wait(self, hand, thing):
        """Out of arm 0's way until arm 0 has brought the payload within COME_IN of the handover."""
        near = np.linalg.norm(self._handle_point(1)[:2] - self._handover()) < COME_IN
        self._advance(near and self.partner.phase in ("payload carry", "payload hold"))
        return np.r_[HANDOVER + [0, WAIT_BACK], CARRY_HEIGHT], 0.0, False

    def _lower(self, hand, thing):
        """Down into the target bin until the payload touches its floor."""
        self.timer += 1
        self._advance(self.transport.payload_in_target_bin or self.timer > LOWER_STEPS)
        return hand - [0, 0, 0.02], 0.0, True


class TransportExpert:
    """Transport's expert, both arms at once (`LidArm`, `TrashArm`)."""

    def __init__(self, env, grasp_shift: np.ndarray, goal_shift: np.ndarray):
        self.arms = (LidArm(env, grasp_shift, goal_shift), TrashArm(env, grasp_shift, goal_shift))
        self.arms[0].partner, self.arms[1].partner = self.arms[1], self.arms[0]

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The 14 actions, arm 0's 7 then arm 1's, for observation `obs` (each arm's ARM_OBS numbers
        start with its hand's position)."""
        return np.concatenate([arm.act(obs[ARM_OBS * arm.arm:][:3]) for arm in self.arms])


def slide_into_bin(offset: np.ndarray, axis: np.ndarray, along: float) -> float:
    """The point on a handle `along` it (m from its centre, on `axis`), or the nearest one, where the
    palm across the handle stays clear of the bin's walls; `offset`: the handle's centre from the
    bin's, in x, y."""
    reach = PALM[0] * np.abs(axis[::-1]) + PALM[1] * np.abs(axis)  # the palm's half extent in x, y
    room = BIN_INSIDE - WALL_MARGIN - reach
    low, high = -HANDLE_REACH, HANDLE_REACH
    for start, step, free in zip(offset, axis, room, strict=True):
        if abs(step) > 1e-6:
            ends = sorted(((-free - start) / step, (free - start) / step))
            low, high = max(low, ends[0]), min(high, ends[1])
    return float(np.clip(along, low, high)) if low <= high else along


def towards(start: np.ndarray, target: np.ndarray, most: float) -> np.ndarray:
    """`target`, or the point `most` m from `start` on the way to it."""
    gap = float(np.linalg.norm(target - start))
    return target if gap <= most else start + (target - start) * most / gap


def heading(vector: np.ndarray) -> float:
    """The direction of `vector` in the table's plane (rad)."""
    return float(np.arctan2(vector[1], vector[0]))


def finger_bodies(model, arm: int) -> list[int]:
    """The bodies of arm `arm`'s two fingers, left and right."""
    return [model.body_name2id(f"gripper{arm}_right_{side}finger") for side in ("left", "right")]


def wrapped(angle: float, period: float) -> float:
    """`angle` shifted by whole periods into [-period / 2, period / 2)."""
    return (angle + period / 2) % period - period / 2


EXPERTS = {"robomimic/lift": lambda env, grasp, goal: PickExpert(env, grasp, goal, place=False),
           "robomimic/can": lambda env, grasp, goal: PickExpert(env, grasp, goal, place=True),
           "robomimic/square": NutExpert, "robomimic/transport": TransportExpert}


def check(task: str) -> None:
    """UserError for a robomimic task without a scripted expert."""
    if task not in EXPERTS:
        raise UserError(f"no scripted expert for {task}; robomimic's are for {', '.join(EXPERTS)}")


def expert(task: str, env, grasp_shift: np.ndarray, goal_shift: np.ndarray) -> Waypoints | TransportExpert:
    """The scripted expert of a robomimic task (`check`ed) for one episode."""
    return EXPERTS[task](env, grasp_shift, goal_shift)

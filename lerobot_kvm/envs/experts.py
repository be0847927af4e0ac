"""Scripted experts shared by scenarios: small state machines on touch, F/T and tracking."""

from collections.abc import Callable

import numpy as np

from .physics import Physics
from .scenario import Expert

HAND_TO_FINGER_CENTRE = 0.035  # finger centre below the hand origin
FINGER_HALF_HEIGHT = 0.035
MOVE_STEP = 0.015  # m per control step while approaching
TOUCH_ON = 0.3  # N on a fingertip that counts as contact
STROKE_STEP = 0.003  # m per control step along a stroke


def touching(physics: Physics) -> bool:
    """Either fingertip touches something: an earlier skill left the gripper on an object."""
    return bool(physics.sensors.touch(physics.data).max() > TOUCH_ON)


def finger_speed(physics: Physics) -> float:
    """How fast the fingers close (m/s, both together): a squeezed object still giving way."""
    return float(physics.data.joint("finger_l").qvel[0] + physics.data.joint("finger_r").qvel[0])


def wrist_pitch(physics: Physics) -> float:
    """The wrist's sensed pitch: where an expert that turns it carries on from when it takes over."""
    return float(physics.sensors.arm_position(physics.data)[3])


class GraspLiftExpert(Expert):
    """Approach from above, descend, squeeze with a fixed grip command, lift, hold.

    The grip level is the skill: a firm squeeze and a gentle one are two experts of this class. So is the lift:
    `lift_step` m per control step, after an optional slow lift-off (`liftoff` m at `liftoff_step` m per step)
    that eases a heavy or slippery object off the table. The hand stops rising once it is `lift` above the grasp
    height or, when `top` is given, at that absolute height (world z). With `still` the grasp waits, before it
    lifts, until the fingers close slower than `still` m/s (a squeeze that lets a yielding object finish giving
    way). Subclasses replace `after_grasp` to do something else with the held object.
    """

    def __init__(
        self,
        body: str,
        grip: float,
        lift: float = 0.12,
        grasp_height: float | None = None,
        *,
        lift_step: float = 0.01,
        liftoff: float = 0.0,
        liftoff_step: float = 0.005,
        top: float | None = None,
        still: float | None = None,
    ) -> None:
        self.body = body
        self.grip = grip
        self.lift = lift
        self.grasp_height = grasp_height
        self.lift_step, self.liftoff, self.liftoff_step, self.top = lift_step, liftoff, liftoff_step, top
        self.still = still
        self.phase = "approach"
        self.settle = 0
        self.timer = 0
        self.anchor = np.zeros(3)
        self.base = 0.0  # hand height when the object was grasped

    def act(self, physics: Physics) -> np.ndarray:
        obj = physics.data.body(self.body).xpos
        pos = physics.sensors.arm_position(physics.data)
        touch = physics.sensors.touch(physics.data)
        centre = obj[2] if self.grasp_height is None else self.grasp_height
        grasp_z = max(centre + HAND_TO_FINGER_CENTRE, FINGER_HALF_HEIGHT * 2 + 0.006)
        hover_z = grasp_z + 0.06
        target = pos[:3].copy()
        grip = -1.0
        self.timer += 1
        if self.phase == "approach":
            goal = np.array([obj[0], obj[1], hover_z])
            target = pos[:3] + np.clip(goal - pos[:3], -MOVE_STEP, MOVE_STEP)
            if np.linalg.norm(goal - pos[:3]) < 0.004:
                self.phase = "descend"
        elif self.phase == "descend":
            goal = np.array([obj[0], obj[1], grasp_z])
            target = pos[:3] + np.clip(goal - pos[:3], -MOVE_STEP, MOVE_STEP)
            if abs(pos[2] - grasp_z) < 0.003:
                self.phase, self.timer, self.anchor = "close", 0, goal
        elif self.phase == "close":
            target = self.anchor
            grip = self.grip
            held = touch.min() > TOUCH_ON and (self.still is None or finger_speed(physics) < self.still)
            self.settle = self.settle + 1 if held else 0
            if self.settle >= 4 or self.timer > 30:
                self.phase, self.base = "lift", self.anchor[2]
        else:  # holding the object
            grip = self.grip
            self.anchor = self.after_grasp(physics, grasp_z)
            target = self.anchor
        return np.array([*target, 0.0, grip], dtype=np.float32)

    def resume(self, physics: Physics) -> None:
        """A fingertip on the object (held or being squeezed): keep it and squeeze with this skill's grip from where
        the hand is, then lift as usual; the hand already over the object: descend from there; else approach."""
        pos = physics.sensors.arm_position(physics.data)[:3]
        if touching(physics):
            self.phase, self.timer, self.anchor = "close", 0, pos.copy()
        elif np.linalg.norm(physics.data.body(self.body).xpos[:2] - pos[:2]) < 0.004:
            self.phase = "descend"

    def after_grasp(self, physics: Physics, grasp_z: float) -> np.ndarray:
        """Next hand position while the object is held: rise, then hold."""
        step = self.liftoff_step if self.anchor[2] < self.base + self.liftoff else self.lift_step
        if self.top is None:
            return self.anchor + [0.0, 0.0, step if self.anchor[2] < grasp_z + self.lift else 0.0]
        return self.anchor + [0.0, 0.0, min(step, self.top - self.anchor[2])]


PUSH_GRIP = 0.25  # closes the empty fingers against each other into a pusher (stronger squeezes let them slip past)


class PushExpert(Expert):
    """Close the fingers into a pusher, line up behind `body`, push it along +x at `speed`, stop abruptly, back off.

    The pusher's leading point is `ahead` m in front of the hand origin with the hand at `hand_z` and wrist `pitch`;
    it meets the body's back face (`half_depth` behind its origin) and carries it `distance` m. With `reach_first`
    the hand stays up until it is behind the body (for a low push close to the table). The approach ends, and the push
    at `speed` begins, `standoff` m behind the meeting point.
    """

    def __init__(
        self,
        body: str,
        half_depth: float,
        distance: float,
        *,
        speed: float,
        ahead: float,
        hand_z: float,
        pitch: float = 0.0,
        reach_first: bool = False,
        standoff: float = 0.03,
    ) -> None:
        self.body, self.half_depth, self.distance = body, half_depth, distance
        self.standoff = standoff
        self.speed, self.ahead, self.hand_z, self.pitch, self.reach_first = speed, ahead, hand_z, pitch, reach_first
        self.phase = "approach"
        self.target: np.ndarray | None = None  # set from the hand's position on the first step
        self.goal_x = 0.0
        self.timer = 0

    def act(self, physics: Physics) -> np.ndarray:
        d = physics.data
        obj = d.body(self.body).xpos
        pos = physics.sensors.arm_position(d)
        meet = obj[0] - self.half_depth - self.ahead  # hand x where the pusher meets the back face
        self.timer += 1
        if self.target is None:
            self.target = pos[:3].copy()
        if self.phase == "approach":
            start = np.array([meet - self.standoff, obj[1], self.hand_z])
            step = np.clip(start - self.target, -MOVE_STEP, MOVE_STEP)
            if self.reach_first and np.linalg.norm(start[:2] - self.target[:2]) > 0.01:
                step[2] = max(step[2], 0.0)
            self.target = self.target + step
            closed = physics.sensors.finger_width(d) > 0.085
            if np.linalg.norm(start - pos[:3]) < 0.004 and closed:
                self.phase = "push"
                self.goal_x = meet + self.distance + 0.005
        elif self.phase == "push":
            self.target[0] = min(self.target[0] + self.speed, self.goal_x)
            if self.target[0] >= self.goal_x:
                self.phase, self.timer = "hold", 0
        elif self.timer > 8:  # back off once the object has come to rest
            self.target[0] = max(self.target[0] - 0.004, self.goal_x - 0.03)
        return np.array([*self.target, self.pitch, PUSH_GRIP], dtype=np.float32)


class StrokeExpert(Expert):
    """Hover over a line's start, take the wrist's free-air force, descend until it feels contact, press, stroke +x.

    A guarded move: the contact height is where the wrist force sensor first feels the surface (`contact_force` N
    above its free-air reading); the hand is then commanded `press_depth` below it (at most `press_step` m deeper
    per step), and after `press_steps` steps strokes along +x. The position loop (1500 N/m) in series with what
    the tool presses on sets the force: about kp * depth on a hard surface, less on one that gives way.
    `line(physics)` gives the hover point over the start and the end x, each step. The free-air force is read
    holding still for `settle_steps` steps, or with `settle_steps=0` on the way down at descend step
    `free_air_step` (contact counts only after it).
    """

    def __init__(
        self,
        line: Callable[[Physics], tuple[np.ndarray, float]],
        press_depth: float,
        *,
        descend_step: float,
        contact_force: float,
        press_step: float,
        press_steps: int,
        settle_steps: int = 0,
        free_air_step: int = 0,
    ) -> None:
        self.line, self.press_depth = line, press_depth
        self.descend_step, self.contact_force, self.press_step, self.press_steps = (
            descend_step,
            contact_force,
            press_step,
            press_steps,
        )
        self.settle_steps, self.free_air_step = settle_steps, free_air_step
        self.phase = "approach"
        self.target: np.ndarray | None = None  # set from the hand's position on the first step
        self.baseline = 0.0
        self.contact_z = 0.0
        self.timer = 0

    def _wrist_z(self, physics: Physics) -> float:
        return float(physics.data.sensor("wrist_force").data[2])

    def act(self, physics: Physics) -> np.ndarray:
        pos = physics.sensors.arm_position(physics.data)
        self.timer += 1
        if self.target is None:
            self.target = pos[:3].copy()
        hover, end_x = self.line(physics)
        if self.phase == "approach":
            self.target = self.target + np.clip(hover - self.target, -MOVE_STEP, MOVE_STEP)
            if np.linalg.norm(hover - pos[:3]) < 0.003 and self.timer > 10:
                self.phase, self.timer = ("settle" if self.settle_steps else "descend"), 0
        elif self.phase == "settle":  # read the free-air wrist force before touching anything
            self.baseline = self._wrist_z(physics)
            if self.timer >= self.settle_steps:
                self.phase = "descend"
        elif self.phase == "descend":
            self.target[2] -= self.descend_step
            if self.timer == self.free_air_step:  # free-air reading while moving, well above the surface
                self.baseline = self._wrist_z(physics)
            if self.timer > self.free_air_step and self.baseline - self._wrist_z(physics) > self.contact_force:
                self.contact_z = pos[2]
                self.target[2] = pos[2]  # start pressing from where the tool met the surface
                self.phase, self.timer = "press", 0
        elif self.phase in ("press", "stroke"):
            self.target[2] = max(self.target[2] - self.press_step, self.contact_z - self.press_depth)
            if self.phase == "press" and self.timer > self.press_steps:
                self.phase = "stroke"
            if self.phase == "stroke":
                self.target[0] = min(self.target[0] + STROKE_STEP, end_x)
        return np.array([*self.target, 0.0, -1.0], dtype=np.float32)

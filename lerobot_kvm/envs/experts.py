"""Scripted experts shared by scenarios: small state machines on touch, F/T and tracking."""

import numpy as np

from .physics import Physics
from .scenario import Expert

HAND_TO_FINGER_CENTRE = 0.035  # finger centre below the hand origin
FINGER_HALF_HEIGHT = 0.035
MOVE_STEP = 0.015  # m per control step while approaching
TOUCH_ON = 0.3  # N on a fingertip that counts as contact


class GraspLiftExpert(Expert):
    """Approach from above, descend, squeeze with a fixed grip command, lift, hold.

    The grip level is the skill: a firm squeeze and a gentle one are two experts of this class. So is the lift:
    `lift_step` m per control step, after an optional slow lift-off (`liftoff` m at `liftoff_step` m per step)
    that eases a heavy or slippery object off the table. The hand stops rising once it is `lift` above the grasp
    height or, when `top` is given, at that absolute height (world z). Subclasses replace `after_grasp` to do
    something else with the held object.
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
    ) -> None:
        self.body = body
        self.grip = grip
        self.lift = lift
        self.grasp_height = grasp_height
        self.lift_step, self.liftoff, self.liftoff_step, self.top = lift_step, liftoff, liftoff_step, top
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
            both = touch.min() > TOUCH_ON
            self.settle = self.settle + 1 if both else 0
            if self.settle >= 4 or self.timer > 30:
                self.phase, self.base = "lift", self.anchor[2]
        else:  # holding the object
            grip = self.grip
            self.anchor = self.after_grasp(physics, grasp_z)
            target = self.anchor
        return np.array([*target, 0.0, grip], dtype=np.float32)

    def after_grasp(self, physics: Physics, grasp_z: float) -> np.ndarray:
        """Next hand position while the object is held: rise, then hold."""
        step = self.liftoff_step if self.anchor[2] < self.base + self.liftoff else self.lift_step
        if self.top is None:
            return self.anchor + [0.0, 0.0, step if self.anchor[2] < grasp_z + self.lift else 0.0]
        return self.anchor + [0.0, 0.0, min(step, self.top - self.anchor[2])]

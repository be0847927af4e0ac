"""The grasp-and-lift family: scenarios won by grasping one body and lifting it clear of the table."""

from typing import Any, ClassVar

import numpy as np

from .physics import Physics
from .scenario import Scenario, StepOutcome

HELD_STEPS = 5  # control steps in a row the object must stay lifted and held for success
TOUCH_HELD = 0.05  # N on each fingertip that counts as holding


class GraspLiftScenario(Scenario):
    """Success: `body` lifted `lift_height` above its resting height `rest_z` (world z of its origin on the table)
    and touched by both fingers, for `HELD_STEPS` control steps in a row. Its skills are `GraspLiftExpert`s on
    `body`, built with `grasp` (options every skill shares) and the skill's own parameters (usually the grip).

    Subclasses call `reset` first in theirs and end `evaluate` with `held_aloft` once no catastrophe happened.
    """

    body: ClassVar[str]
    rest_z: ClassVar[float] = 0.0
    lift_height: ClassVar[float]
    grasp: ClassVar[dict[str, Any]] = {}

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        self._lifted_body = physics.model.body(self.body).id
        self._held = 0

    def lifted(self, physics: Physics) -> bool:
        """The object is high enough to count as lifted."""
        return bool(physics.data.xpos[self._lifted_body][2] > self.rest_z + self.lift_height)

    def held_aloft(self, physics: Physics) -> StepOutcome:
        held = self.lifted(physics) and physics.sensors.touch(physics.data).min() > TOUCH_HELD
        self._held = self._held + 1 if held else 0
        return StepOutcome(success=self._held >= HELD_STEPS)

    def expert_context(self) -> dict[str, Any]:
        return {"body": self.body, **self.grasp}

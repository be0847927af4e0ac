"""C15 paper towel roll, with vs without a core: a firm grip around the middle crushes a coreless roll.

The roll stands on the table and is grasped around its middle. Where the fingers press, the
paper layers are two pads on spring mounts (radial slide joints). With a cardboard core the
layers give 3 mm and then the core takes the load (the joint's range). A coreless roll is soft
all the way in and its layers yield (MuJoCo joint-spring plasticity, `springyield`) above 8 N,
flattening permanently, read from `data.plastic`.
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import GraspLiftExpert
from ..grasp_lift import GraspLiftScenario
from ..physics import Physics, permanent_set, set_free_body_pose, yielding_spring
from ..scenario import StepOutcome, register_scenario
from ..scene import SceneParts, scenario_parts, vector

RADIUS = 0.035
HALF_HEIGHT = 0.04
GRASP_HEIGHT = 0.05  # finger centre height: the fingers cover the roll's middle, the palm clears its top
LIFT_HEIGHT = 0.05
PAPER_RGB = np.array([0.93, 0.93, 0.90])
CORE_RGBA = {
    "prior": (0.62, 0.45, 0.28, 1.0),
    "shifted": (0.90, 0.90, 0.86, 1.0),
    "control": (0.55, 0.40, 0.25, 1.0),
}
# variant -> (mass kg, layer stiffness N/m, travel m before the core stops it, yield deflection m)
ROLL = {
    "prior": (0.12, 3000.0, 0.003, 1.0),
    "shifted": (0.10, 800.0, 0.02, 0.01),
    "control": (0.22, 4000.0, 0.002, 1.0),  # a heavier, tighter-wound roll on a core
}
CRUSH = 0.003  # m of permanent flattening that counts as a crushed roll


@register_scenario
class PaperTowelRoll(GraspLiftScenario):
    info = SCENARIO_INFOS["paper_towel_roll"]
    skills = {"firm_grasp": partial(GraspLiftExpert, grip=0.75), "gentle_grasp": partial(GraspLiftExpert, grip=0.15)}
    body, rest_z, lift_height, grasp = "roll", HALF_HEIGHT, LIFT_HEIGHT, {"grasp_height": GRASP_HEIGHT}

    def parts(self) -> SceneParts:
        r, hh = RADIUS, HALF_HEIGHT
        return scenario_parts(
            "paper_towel_roll",
            hh=hh,
            base_r=r - 0.001,
            base_z=-hh + 0.004,
            outer_r=r - 0.0005,
            outer_hh=hh - 0.0005,
            core_hh=hh + 0.0005,
            hole_hh=hh + 0.001,
            layers_y=r - 0.006,
            layers_hz=hh - 0.008,
            yield_=ROLL["shifted"][3],
            rgb=vector(PAPER_RGB, ".3f"),
            core=vector(CORE_RGBA["prior"]),
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        super().reset(physics, variant, rng)
        model, data = physics.model, physics.data
        self._bid = model.body("roll").id
        mass, stiffness, travel, yield_ = ROLL[variant]
        model.body_mass[self._bid] = mass
        self._plastic = [yielding_spring(model, f"layers_{side}", stiffness, yield_, travel) for side in "lr"]
        mujoco.mj_setConst(model, data)  # subtree masses and constraint weights follow the new mass
        rgb = PAPER_RGB + rng.uniform(-0.015, 0.015, 3)
        for name in ("roll_base", "roll_outer", "layers_l", "layers_r"):
            model.geom_rgba[model.geom(name).id] = [*rgb, 1.0]
        core = np.array(CORE_RGBA[variant])
        core[:3] += rng.uniform(-0.015, 0.015, 3)
        model.geom_rgba[model.geom("roll_core").id] = core
        xy = rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "roll", [xy[0], xy[1], HALF_HEIGHT], yaw=rng.uniform(-0.15, 0.15))
        self.flattening = 0.0

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        self.flattening = permanent_set(d, *self._plastic)
        if self.flattening > CRUSH:
            return StepOutcome(catastrophe="crush")
        return self.held_aloft(physics)

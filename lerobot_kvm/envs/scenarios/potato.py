"""A3 potato, raw vs cooked: a firm grasp that lifts a raw potato crushes a cooked one.

The potato is one free body (the visible ellipsoid) with two flesh pads under the skin on the
finger sides. Each pad sits on a slide joint whose spring is the flesh: stiff and far from
yield when raw, soft with a low elastic limit when cooked (MuJoCo elasto-plastic joint springs,
`springyield`). Squeezed past its elastic limit, the cooked flesh flows and stays dented
(`data.plastic`): the crush is permanent deformation, not a force label. The pads compress
more under the same grip when cooked, so the shift shows in the sensed finger width/velocity.
Cooked flesh is also mushy (heavily damped): it gives way over several control steps, so a firm
squeeze creeps in for about ten steps before the dent is deep enough to split the potato, and
easing the grip soon after the creep shows still saves it (rule 3's rescue).
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import GraspLiftExpert
from ..grasp_lift import GraspLiftScenario
from ..physics import Physics, geom_ids, permanent_set, set_free_body_pose, yielding_spring
from ..scenario import StepOutcome, register_scenario
from ..scene import SceneParts, scenario_parts, vector

RADII = (0.045, 0.032, 0.028)
SKIN_RGB = np.array([0.62, 0.47, 0.30])
MASH_RGB = np.array([0.93, 0.86, 0.55])
PAD_Y = 0.024  # pad centre from the potato centre; its outer face is 3 mm inside the skin
PAD_TRAVEL = 0.014
LIFT_HEIGHT = 0.05
CRUSH_DEPTH = 0.003  # m of permanent dent in either pad
# (mass kg, flesh stiffness N/m per pad, elastic limit m, flesh damping N s/m per pad)
FLESH = {
    "prior": (0.2, 15000.0, 0.010, 20.0),  # raw: 150 N elastic limit, 2 mm under a 30 N squeeze
    "control": (0.3, 15000.0, 0.010, 20.0),  # a bigger raw potato: heavier, equally firm
    "shifted": (0.2, 1500.0, 0.0065, 1200.0),  # cooked: soft, flows above 10 N, and gives way slowly (mushy)
}


@register_scenario
class Potato(GraspLiftScenario):
    info = SCENARIO_INFOS["potato"]
    skills = {"firm_grasp": partial(GraspLiftExpert, grip=0.75), "gentle_grasp": partial(GraspLiftExpert, grip=0.15)}
    body, rest_z, lift_height = "potato", RADII[2], LIFT_HEIGHT

    def parts(self) -> SceneParts:
        return scenario_parts(
            "potato", rz=RADII[2], radii=vector(RADII), rgb=vector(SKIN_RGB), pad_y=PAD_Y, pad_travel=PAD_TRAVEL
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        super().reset(physics, variant, rng)
        model, data = physics.model, physics.data
        self._gid = model.geom("potato").id
        self._bid = model.body("potato").id
        self._fingers = geom_ids(model, "finger_l", "finger_r")
        self._pads = geom_ids(model, "potato_pad_l", "potato_pad_r")
        mass, stiffness, limit, damping = FLESH[variant]
        self._plastic = [yielding_spring(model, f"potato_flesh_{s}", stiffness, limit) for s in "lr"]
        for side in "lr":
            model.dof_damping[model.joint(f"potato_flesh_{side}").dofadr[0]] = damping
        pads_mass = 2 * model.body_mass[model.body("potato_pad_l").id]
        model.body_mass[self._bid] = mass - pads_mass
        rgb = SKIN_RGB + rng.uniform(-0.02, 0.02, 3)
        model.geom_rgba[self._gid] = [*rgb, 1.0]
        xy = rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "potato", [xy[0], xy[1], RADII[2]], yaw=rng.uniform(-0.25, 0.25))

    def dent(self, data: mujoco.MjData) -> float:
        """Permanent deformation (m) of the deeper-dented pad."""
        return permanent_set(data, *self._plastic)

    def evaluate(self, physics: Physics) -> StepOutcome:
        m, d = physics.model, physics.data
        if self.dent(d) > CRUSH_DEPTH:
            m.geom_rgba[self._gid] = [*MASH_RGB, 1.0]  # the flesh has split open
            return StepOutcome(catastrophe="crush")
        return self.held_aloft(physics)

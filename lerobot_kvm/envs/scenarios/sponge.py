"""A2 sponge, dry vs wet: a light, quick pinch that lifts a dry sponge loses a soaked one.

One compiled sponge serves every variant; only its hidden mass and surface friction change in
`reset`. Soaked, the sponge is ten times heavier and slippery: the low squeeze still lifts it off
the table, but the brisk lift that suits a dry sponge needs more friction than the weak grasp
gives, the sponge slides down out of the fingers mid-lift and falls back (a "drop"). A firm
squeeze with a steady lift carries it. The wrist force and the fingertip loads show the extra
weight as soon as the lift starts (rule 3).
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import GraspLiftExpert
from ..grasp_lift import GraspLiftScenario
from ..physics import Physics, contact_normal_force, geom_ids, set_free_body_pose
from ..scenario import StepOutcome, register_scenario
from ..scene import SceneParts, scenario_parts, vector

HALF = (0.045, 0.03, 0.02)  # sponge half extents (m)
SPONGE_RGB = np.array([0.93, 0.80, 0.25])
LIFT_HEIGHT = 0.08  # success: bottom this far above the table
LIFTOFF = 0.025  # both skills ease the sponge off the table by this much at LIFTOFF_STEP m per step
LIFTOFF_STEP = 0.005
HAND_TOP = 0.216  # world z the hand lifts to: 14 cm above where it grasps
AIRBORNE = 0.01  # bottom this far above the table counts as lifted
# variant -> (mass kg, surface friction)
BODY = {
    "prior": (0.04, 1.0),  # dry
    "control": (0.09, 0.9),  # damp: twice as heavy, a little slicker; a light grasp still holds it
    "shifted": (0.35, 0.6),  # soaked
}


@register_scenario
class Sponge(GraspLiftScenario):
    info = SCENARIO_INFOS["sponge"]
    skills = {
        "light_grasp": partial(GraspLiftExpert, grip=0.1, lift_step=0.04),
        "firm_grasp": partial(GraspLiftExpert, grip=0.6, lift_step=0.01),
    }
    body, rest_z, lift_height = "sponge", HALF[2], LIFT_HEIGHT
    grasp = {"liftoff": LIFTOFF, "liftoff_step": LIFTOFF_STEP, "top": HAND_TOP}

    def parts(self) -> SceneParts:
        return scenario_parts("sponge", hz=HALF[2], half=vector(HALF), rgb=vector(SPONGE_RGB))

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        super().reset(physics, variant, rng)
        model, data = physics.model, physics.data
        self._gid = model.geom("sponge").id
        self._bid = model.body("sponge").id
        self._sponge = geom_ids(model, "sponge")
        self._fingers = geom_ids(model, "finger_l", "finger_r")
        mass, mu = BODY[variant]
        model.body_mass[self._bid] = mass
        model.body_inertia[self._bid] = mass / 3.0 * (np.sum(np.square(HALF)) - np.square(HALF))  # solid box
        model.geom_friction[self._gid, 0] = mu
        mujoco.mj_setConst(model, data)  # refresh the solver's inverse-weight estimates for the new mass
        model.geom_rgba[self._gid] = [*(SPONGE_RGB + rng.uniform(-0.02, 0.02, 3)), 1.0]
        self._airborne = False
        xy = rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "sponge", [xy[0], xy[1], HALF[2]], yaw=rng.uniform(-0.15, 0.15))

    def evaluate(self, physics: Physics) -> StepOutcome:
        m, d = physics.model, physics.data
        height = d.xpos[self._bid][2] - HALF[2]
        gripped = contact_normal_force(d, m, self._sponge, self._fingers) > 0.05
        if height > AIRBORNE and gripped:
            self._airborne = True
        if self._airborne and not gripped:
            return StepOutcome(catastrophe="drop")
        return self.held_aloft(physics)

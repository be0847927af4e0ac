"""C16 plate, sturdy vs disposable: lifting a loaded plate by its near rim folds a paper plate.

A rectangular plate with a piece of cake on it rests on a small central stand. The plate is two
bodies joined by a hinge along x just inside its near rim: a narrow rim strip and the main plate.
A sturdy (melamine) plate is rigid: the hinge is locked by an equality constraint, active in the
prior variant. A disposable paper plate bends there: the hinge is free with a weak spring, so
when the plate is lifted by its rim alone the main part folds down under the cake's weight and
the cake slides off. Carried on the fingers slid underneath, one under each side, either plate
stays flat.
"""

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..physics import Physics, set_free_body_pose
from ..scenario import Expert, Scenario, StepOutcome, register_scenario
from ..scene import SceneParts, scenario_parts, vector

HALF_X = 0.05  # plate half depth along x (the fingers slide in along +x)
HALF_Y = 0.095  # plate half width along y
FLOOR = 0.002  # half thickness of the plate
STAND_H = 0.045  # height of the stand the plate rests on
HINGE_Y = -0.068  # the fold line, 2.7 cm inside the near rim
LIP_H = 0.01  # half height of the near rim's lip
LIP_T = 0.004  # half thickness of the lip (a rolled rim)
CAKE = (0.0125, 0.0125, 0.01)
LIFT = 0.04  # success: plate lifted this far with the cake still on it
PLATE_RGB = {"prior": np.array([0.93, 0.93, 0.95]), "shifted": np.array([0.95, 0.95, 0.93])}
# variant -> (main plate mass kg, rim strip mass kg, hinge locked, hinge stiffness N m/rad)
PLATE = {"prior": (0.17, 0.03, True, 0.05), "shifted": (0.025, 0.005, False, 0.05)}
X0 = 0.03  # plate centre on the stand


def _step_towards(target: np.ndarray, goal: np.ndarray, step: float) -> np.ndarray:
    return target + np.clip(goal - target, -step, step)


class RimLiftExpert(Expert):
    """Pinch the near rim's lip between the fingers with a firm grip and lift."""

    GRIP = 0.75

    def __init__(self) -> None:
        self.phase = "approach"
        self.target: np.ndarray | None = None  # set from the hand's position on the first step
        self.grasp_z = 0.0
        self.timer = 0

    def act(self, physics: Physics) -> np.ndarray:
        d = physics.data
        rim = d.body("plate_rim").xpos
        lip_y = rim[1] - (HINGE_Y + HALF_Y) / 2 + LIP_T
        pos = physics.sensors.arm_position(d)
        self.timer += 1
        if self.target is None:
            self.target = pos[:3].copy()
        if self.phase in ("approach", "descend"):
            self.grasp_z = rim[2] + FLOOR + 0.003 + 0.07  # fingertips just above the plate's floor
        grasp_z = self.grasp_z
        grip = -1.0
        if self.phase == "approach":
            self.target = _step_towards(self.target, np.array([rim[0], lip_y, grasp_z + 0.05]), 0.015)
            if np.linalg.norm(self.target - pos[:3]) < 0.004 and self.timer > 6:
                self.phase = "descend"
        elif self.phase == "descend":
            self.target = _step_towards(self.target, np.array([rim[0], lip_y, grasp_z]), 0.01)
            if abs(pos[2] - grasp_z) < 0.003:
                self.phase, self.timer = "close", 0
        elif self.phase == "close":
            grip = self.GRIP
            if (physics.sensors.touch(d).min() > 0.3 and self.timer > 4) or self.timer > 25:
                self.phase = "lift"
        else:
            grip = self.GRIP
            self.target[2] = min(self.target[2] + 0.008, grasp_z + LIFT + 0.03)
        return np.array([*self.target, 0.0, grip], dtype=np.float32)


class SupportLiftExpert(Expert):
    """Turn the fingers level (wrist pitched by -90 degrees), slide them in under both sides of the
    plate, clear of the stand, and lift it flat."""

    PITCH = -np.pi / 2
    TINE = 0.012  # half thickness of a finger, now vertical

    def __init__(self) -> None:
        self.phase = "turn"
        self.target: np.ndarray | None = None  # set from the hand's position on the first step
        self.timer = 0

    def act(self, physics: Physics) -> np.ndarray:
        d = physics.data
        plate = d.body("plate_rim").xpos
        near_x = plate[0] - HALF_X
        pos = physics.sensors.arm_position(d)
        self.timer += 1
        if self.target is None:
            self.target = pos[:3].copy()
        tine_z = STAND_H - self.TINE - 0.003  # fingers' top just under the plate's underside
        pitch = self.PITCH
        if self.phase == "turn":  # turn the wrist up in the air, away from the plate
            self.target = _step_towards(self.target, np.array([near_x - 0.09, 0.0, 0.15]), 0.015)
            if self.timer > 12 and np.linalg.norm(self.target - pos[:3]) < 0.004:
                self.phase = "lower"
        elif self.phase == "lower":
            self.target = _step_towards(self.target, np.array([near_x - 0.09, 0.0, tine_z]), 0.015)
            if np.linalg.norm(self.target - pos[:3]) < 0.003:
                self.phase = "insert"
        elif self.phase == "insert":  # slide in until the palm is just short of the plate's edge
            self.target = _step_towards(self.target, np.array([near_x - 0.004, 0.0, tine_z]), 0.008)
            if np.linalg.norm(self.target - pos[:3]) < 0.003:
                self.phase = "lift"
        else:
            self.target[2] = min(self.target[2] + 0.006, tine_z + LIFT + 0.03)
        return np.array([*self.target, pitch, -1.0], dtype=np.float32)


@register_scenario
class Plate(Scenario):
    info = SCENARIO_INFOS["plate"]
    skills = {"rim_lift": RimLiftExpert, "support_lift": SupportLiftExpert}

    def parts(self) -> SceneParts:
        strip_half = (HINGE_Y + HALF_Y) / 2
        main_half = (HALF_Y - HINGE_Y) / 2
        return scenario_parts(
            "plate",
            x0=X0,
            stand_hz=STAND_H / 2,
            rim_y=-HALF_Y + strip_half,
            plate_z=STAND_H + FLOOR,
            hx=HALF_X,
            strip_half=strip_half,
            floor=FLOOR,
            lip_hx=HALF_X - 0.005,
            lip_t=LIP_T,
            lip_h=LIP_H,
            lip_y=-strip_half + LIP_T,
            main_half=main_half,
            far_y=2 * main_half - 0.002,
            cake_z=STAND_H + 2 * FLOOR + CAKE[2],
            cake=vector(CAKE),
            cake_hx=CAKE[0],
            cake_hy=CAKE[1],
            cake_hz=CAKE[2],
            rgb=vector(PLATE_RGB["prior"], ".3f"),
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        main, strip, locked, stiffness = PLATE[variant]
        self._plate = model.body("plate").id
        self._rim = model.body("plate_rim").id
        self._cake = model.body("cake").id
        model.body_mass[self._plate] = main
        model.body_mass[self._rim] = strip
        model.body_inertia[self._plate] = main / 3 * np.array([HALF_Y**2, HALF_X**2, HALF_X**2 + HALF_Y**2]) / 2
        model.body_inertia[self._rim] = strip / 3 * np.array([0.0002, HALF_X**2, HALF_X**2])
        model.jnt_stiffness[model.joint("plate_fold").id] = stiffness
        mujoco.mj_setConst(model, data)  # subtree masses and constraint weights follow the new masses
        data.eq_active[model.equality("plate_rigid").id] = locked
        rgb = PLATE_RGB[variant] + rng.uniform(-0.02, 0.02, 3)
        for name in ("plate_rim", "plate_lip", "plate", "plate_rim_far"):
            model.geom_rgba[model.geom(name).id] = [*np.clip(rgb, 0, 1), 1.0]
        dx = rng.uniform(-0.01, 0.01)
        strip_half = (HINGE_Y + HALF_Y) / 2
        set_free_body_pose(model, data, "plate_rim", [X0 + dx, -HALF_Y + strip_half, STAND_H + FLOOR])
        cake_xy = [X0 + dx + rng.uniform(-0.012, 0.012), 0.02 + rng.uniform(-0.01, 0.01)]
        set_free_body_pose(model, data, "cake", [*cake_xy, STAND_H + 2 * FLOOR + CAKE[2]], yaw=rng.uniform(-0.3, 0.3))
        self._held = 0

    def cake_on_plate(self, data: mujoco.MjData) -> bool:
        """The cake rests on the main plate: above its floor and within its outline (in its frame)."""
        rel = data.xmat[self._plate].reshape(3, 3).T @ (data.xpos[self._cake] - data.xpos[self._plate])
        main_half = (HALF_Y - HINGE_Y) / 2
        return abs(rel[0]) < HALF_X and -0.005 < rel[1] < 2 * main_half and 0.0 < rel[2] < 0.03

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        plate_z = d.xpos[self._rim][2]
        if not self.cake_on_plate(d) and d.xpos[self._cake][2] < plate_z - 0.01:
            return StepOutcome(catastrophe="drop")  # the cake slid off the plate
        if plate_z < STAND_H - 0.01:
            return StepOutcome(catastrophe="drop")  # the plate itself fell
        lifted = min(plate_z, d.xpos[self._plate][2]) > STAND_H + FLOOR + LIFT
        level = abs(np.arcsin(np.clip(d.xmat[self._plate][7], -1, 1))) < np.deg2rad(20)
        self._held = self._held + 1 if (lifted and level and self.cake_on_plate(d)) else 0
        return StepOutcome(success=self._held >= 5)

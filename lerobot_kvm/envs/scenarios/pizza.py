"""A5 pizza, cold vs hot: lifting a slice by its crust carries a cold slice but folds a hot one.

The slice is a crust (where it is pinched) followed by three tapering dough segments on bending
hinges, with four pepperoni toppings resting loose on the cheese. Cold, the hinges are stiff: the
slice cantilevers out of the pinch and the toppings ride along. Hot, the same hinges are floppy:
lifted by the crust, the front half folds down and the toppings slide off onto the table (a
"spill"). Sliding the slice to the paper with the crust pinched and the dough supported by the
table moves both intact. Only the hidden bending range of the hinges changes between variants; the
wrist torque of the lifted slice shows the difference (rule 3) during a slow lift-off, well before the hot slice
hangs steeply enough to shed its toppings, and a slide that takes over lowers a lifted slice back onto the table.
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import GraspLiftExpert, touching
from ..physics import Physics, set_free_body_pose
from ..scenario import Scenario, StepOutcome, register_scenario
from ..scene import SceneParts

CRUST = (0.014, 0.034, 0.012)  # half extents
SEG_HX, SEG_HZ = 0.025, 0.004
SEG_HY = (0.031, 0.022, 0.013)  # tapering towards the tip
SEG_MASS = (0.02, 0.015, 0.01)
# Pepperoni: (dough segment, x, y) in the segment frame.
TOPPINGS = [(1, 0.004, 0.0), (2, -0.010, 0.007), (2, 0.010, -0.006), (3, 0.006, 0.0)]
PEPPERONI = (0.0085, 0.002)  # radius, half height of the drawn disc
PEP_BALL = 0.004  # the disc slides on one contact sphere under its centre (cheap, cannot roll: no rotation dofs)
START = np.array([-0.05, 0.05])  # crust centre before jitter
TARGET = np.array([-0.05, -0.06])  # crust goal: the slice then lies on the paper
GOAL_TOL = 0.02
CRUST_RGB = np.array([0.78, 0.56, 0.30])
CHEESE_RGB = np.array([0.96, 0.80, 0.38])
PEP_RGB = np.array([0.70, 0.15, 0.10])
# The lift's first 3 cm at 2 mm per step (15 steps; 1 cm per step before): the hot slice's light wrist torque leaves
# the cold slices' envelope 7 steps into the lift (seed 0 and 1, 20 episodes), while its toppings only reach the table
# after 27 and a switch to the slide still rescues it after 25.
LIFTOFF = 0.03
LIFTOFF_STEP = 0.002
LIFTED = 0.002  # m above its resting height beyond which the crust hangs in the pinch (the slide raises it this much)
HOT_BENDING = (0.002, 0.002)  # stiffness N m/rad, damping N m s/rad of the dough's bending hinges
# Bending range of each hinge (rad): cold dough barely bends, hot dough folds freely.
BEND_RANGE = {"prior": 0.01, "shifted": 2.8}
# Collision bits (the table and the robot use bit 1): toppings touch the dough, crust, table and robot but not one
# another; dough segments touch the toppings, crust, table and robot but not one another.
TOPPING_BITS = 'contype="2" conaffinity="1"'
DOUGH_BITS = 'contype="4" conaffinity="3"'


class CrustPinchExpert(GraspLiftExpert):
    """Pinch the crust, then either lift-carry-lower it (`lift` > 0) or slide it along the table (`lift` == 0).

    The lift starts slowly (`liftoff` m at `LIFTOFF_STEP` m per step): the first centimetres are where the wrist
    feels whether the slice cantilevers or folds, so they take long enough for that to show before the slice is
    high enough to shed its toppings.
    """

    def __init__(self, grip: float, lift: float, carry_step: float, liftoff: float = 0.0) -> None:
        super().__init__("crust", grip, lift, liftoff=liftoff, liftoff_step=LIFTOFF_STEP)
        self.carry_step = carry_step
        self.stage = "raise"

    def resume(self, physics: Physics) -> None:
        """A crust already lifted by another skill stays pinched and is first lowered back onto the table (the
        slide's height); otherwise as any grasp."""
        crust_z = float(physics.data.body("crust").xpos[2])
        if touching(physics) and crust_z > CRUST[2] + LIFTED:
            pos = physics.sensors.arm_position(physics.data)[:3]
            self.phase, self.anchor, self.base = "lift", pos.copy(), pos[2] - (crust_z - CRUST[2])
        else:
            super().resume(physics)

    def after_grasp(self, physics: Physics, grasp_z: float) -> np.ndarray:
        goal = self.anchor.copy()
        if self.stage == "raise":
            goal[2] = self.base + max(self.lift, 0.002)  # sliding lifts the crust just off the table
            if abs(self.anchor[2] - goal[2]) < 1e-6:
                self.stage = "carry"
        elif self.stage == "carry":
            goal[:2] = TARGET
            if np.linalg.norm(self.anchor[:2] - goal[:2]) < 1e-6:
                self.stage = "lower"
        else:
            goal[2] = self.base
        step = self.carry_step if self.stage == "carry" else self.lift_step
        if self.stage == "raise" and self.anchor[2] < self.base + self.liftoff:
            step = self.liftoff_step
        return self.anchor + np.clip(goal - self.anchor, -step, step)


def _rgb(rgb: np.ndarray) -> str:
    return " ".join(str(v) for v in rgb)


def _segments(i: int) -> str:
    if i > len(SEG_HY):
        return ""
    back = CRUST[0] if i == 1 else SEG_HX
    z = SEG_HZ - CRUST[2] if i == 1 else 0.0
    peps = "".join(
        f'\n        <site name="pep_site_{k}" pos="{x} {y} {SEG_HZ + PEP_BALL}" size="0.001"/>'
        for k, (seg, x, y) in enumerate(TOPPINGS)
        if seg == i
    )
    return f"""
      <body name="dough_{i}" pos="{back + SEG_HX} 0 {z}">
        <joint name="bend_{i}" type="hinge" axis="0 1 0" pos="{-SEG_HX} 0 0" range="-2.8 2.8" solreflimit="0.004 1"
               stiffness="{HOT_BENDING[0]}" damping="{HOT_BENDING[1]}"/>
        <geom name="dough_{i}" type="box" size="{SEG_HX} {SEG_HY[i - 1]} {SEG_HZ}" mass="{SEG_MASS[i - 1]}"
              priority="1" condim="1" {DOUGH_BITS} rgba="{_rgb(CHEESE_RGB)} 1"/>{peps}{_segments(i + 1)}
      </body>"""


@register_scenario
class Pizza(Scenario):
    info = SCENARIO_INFOS["pizza"]
    skills = {
        "pinch_lift": partial(CrustPinchExpert, grip=0.5, lift=0.18, carry_step=0.01, liftoff=LIFTOFF),
        "supported_slide": partial(CrustPinchExpert, grip=0.5, lift=0.0, carry_step=0.005),
    }

    def parts(self) -> SceneParts:
        c = " ".join(str(v) for v in CRUST)
        peps = ""
        for k in range(len(TOPPINGS)):
            slides = "".join(
                f'\n      <joint name="pep_{k}_{a}" type="slide" axis="{v}"/>'
                for a, v in (("x", "1 0 0"), ("y", "0 1 0"), ("z", "0 0 1"))
            )
            peps += f"""
    <body name="pep_{k}" pos="0 0 0">{slides}
      <geom name="pep_{k}" type="sphere" size="{PEP_BALL}" mass="0.003" priority="2" friction="0.6 0.01 0.001"
            condim="3" {TOPPING_BITS} rgba="0 0 0 0" group="3"/>
      <geom name="pep_{k}_disc" type="mesh" mesh="pepperoni" pos="0 0 {PEPPERONI[1] - PEP_BALL}"
            contype="0" conaffinity="0" mass="0" rgba="{_rgb(PEP_RGB)} 1"/>
    </body>"""
        angles = np.linspace(0, 2 * np.pi, 10, endpoint=False)  # a decagonal disc renders cheaply
        disc = " ".join(
            f"{PEPPERONI[0] * np.cos(a):.5f} {PEPPERONI[0] * np.sin(a):.5f} {z}"
            for a in angles
            for z in (-PEPPERONI[1], PEPPERONI[1])
        )
        return SceneParts(
            assets=f'<mesh name="pepperoni" vertex="{disc}"/>',
            worldbody=f"""
    <geom name="paper" type="box" size="0.095 0.045 0.0005" pos="{TARGET[0] + 0.075} {TARGET[1]} 0.0005"
          rgba="0.95 0.95 0.92 1" contype="0" conaffinity="0"/>
    <body name="crust" pos="0 0 {CRUST[2]}">
      <freejoint name="crust"/>
      <geom name="crust" type="box" size="{c}" mass="0.03" friction="0.8 0.01 0.001"
            rgba="{_rgb(CRUST_RGB)} 1"/>{_segments(1)}
    </body>{peps}""",
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        # The slice rests untouched until the gripper reaches it; the engine skips resting bodies while they sleep.
        if not model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP:
            model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
            mujoco.mj_resetData(model, data)  # sets up the sleep bookkeeping the first reset ran without
        self._crust = model.body("crust").id
        self._is_pep = np.zeros(model.ngeom, dtype=bool)
        self._is_pep[[model.geom(f"pep_{k}").id for k in range(len(TOPPINGS))]] = True
        self._table = model.geom("table").id
        self._dough = [model.geom(f"dough_{i}").id for i in range(1, len(SEG_HY) + 1)]
        for i in range(1, len(SEG_HY) + 1):
            model.jnt_range[model.joint(f"bend_{i}").id] = [-BEND_RANGE[variant], BEND_RANGE[variant]]
        jitter = rng.uniform(-0.02, 0.02, 3)
        model.geom_rgba[model.geom("crust").id] = [*(CRUST_RGB + jitter), 1.0]
        for g in self._dough:
            model.geom_rgba[g] = [*(CHEESE_RGB + jitter), 1.0]
        for k in range(len(TOPPINGS)):
            model.geom_rgba[model.geom(f"pep_{k}_disc").id] = [*(PEP_RGB + jitter), 1.0]
        xy = START + rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "crust", [xy[0], xy[1], CRUST[2]], yaw=rng.uniform(-0.1, 0.1))
        mujoco.mj_kinematics(model, data)
        for k in range(len(TOPPINGS)):
            adr = model.jnt_qposadr[model.joint(f"pep_{k}_x").id]
            data.qpos[adr : adr + 3] = data.site(f"pep_site_{k}").xpos
        self._done = 0

    def spilled(self, data: mujoco.MjData) -> bool:
        """A topping lies on the table."""
        pairs = data.contact.geom  # (ncon, 2) geom ids of the active contacts
        return bool(((pairs == self._table).any(axis=1) & self._is_pep[pairs].any(axis=1)).any())

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        if self.spilled(d):
            return StepOutcome(catastrophe="spill")
        crust = d.xpos[self._crust]
        flat = max(d.geom_xpos[g][2] for g in self._dough) < SEG_HZ + 0.004
        placed = np.linalg.norm(crust[:2] - TARGET) < GOAL_TOL and crust[2] < CRUST[2] + 0.004 and flat
        self._done = self._done + 1 if placed else 0
        return StepOutcome(success=self._done >= 3)

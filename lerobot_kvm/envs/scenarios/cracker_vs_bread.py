"""C13 cracker vs soft bread: spreading with firm downward pressure crushes soft bread.

The robot holds a flat spreader (a held tool attached to the hand) and spreads across the top of a
slice lying on the table. The slice's top layer rests on a spring mount (a vertical slide joint):
a hard cracker gives under a millimetre at any force; soft bread gives several millimetres and
its crumb yields (MuJoCo joint-spring plasticity, `springyield`) above about 5 N, staying
flattened, read from `data.plastic`. Spreading with the light pressure of a force-regulated touch
works on both.
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..physics import Physics, contact_normal_force, geom_ids, set_free_body_pose
from ..scenario import Expert, Scenario, StepOutcome, register_scenario
from ..scene import SceneParts

HALF = (0.045, 0.045)  # half size of the slice on the table
BASE_HALF_Z = 0.002
CRUMB = 0.008  # thickness of the crumb (or cracker) between the base and the top layer
TOP_HALF_Z = 0.002
TOP_Z = 2 * BASE_HALF_Z + CRUMB + 2 * TOP_HALF_Z  # height of the top surface at rest
BLADE_BELOW_HAND = 0.099  # the blade's underside below the hand origin
STROKE = 0.05  # spread this far along x across the middle of the slice
BINS = 10  # the stroke in 5 mm bins; success: at least COVER of them spread
COVER = 9
CONTACT_N = 0.3  # blade-on-slice force that counts as spreading
TOP_RGB = {"prior": np.array([0.84, 0.66, 0.36]), "shifted": np.array([0.90, 0.76, 0.52])}
SIDE_RGB = {"prior": np.array([0.78, 0.58, 0.30]), "shifted": np.array([0.74, 0.50, 0.26])}
# variant -> (top-layer stiffness N/m, travel m, yield deflection m): a cracker gives 1 mm and never
# yields within the robot's force; soft bread yields at 800 N/m * 6 mm = 4.8 N
SLICE = {"prior": (3000.0, 0.001, 1.0), "shifted": (800.0, 0.008, 0.006)}
CRUSH = 0.002  # m of permanent flattening that counts as crushed bread


class SpreadExpert(Expert):
    """Hover over the slice, descend until the wrist feels contact, press, stroke along +x.

    A guarded move: the contact height is where the wrist force sensor first feels the slice; the
    hand is then commanded `press_depth` below it. The position loop (1500 N/m) in series with the
    slice presses with about kp * depth on a hard cracker (12 mm: ~15 N, firm; 2 mm: ~2 N, gentle)
    and less on soft bread, which gives way.
    """

    HOVER = 0.02
    DESCEND = 0.002  # m per step once close to the surface
    STROKE_STEP = 0.003  # m per step along the stroke

    def __init__(self, press_depth: float) -> None:
        self.press_depth = press_depth
        self.phase = "approach"
        self.target: np.ndarray | None = None  # set from the hand's position on the first step
        self.baseline = 0.0
        self.contact_z = 0.0
        self.timer = 0

    def _contact_force(self, physics: Physics) -> float:
        """Upward push on the tool, from the wrist force sensor relative to its free-air reading."""
        return self.baseline - float(physics.data.sensor("wrist_force").data[2])

    def act(self, physics: Physics) -> np.ndarray:
        d = physics.data
        slice_xy = d.body("slice").xpos[:2]
        pos = physics.sensors.arm_position(d)
        self.timer += 1
        if self.target is None:
            self.target = pos[:3].copy()
        start = np.array([slice_xy[0] - STROKE / 2 - 0.003, slice_xy[1], TOP_Z + BLADE_BELOW_HAND + self.HOVER])
        if self.phase == "approach":
            self.target = self.target + np.clip(start - self.target, -0.015, 0.015)
            if np.linalg.norm(start - pos[:3]) < 0.003 and self.timer > 10:
                self.phase, self.timer = "settle", 0
        elif self.phase == "settle":  # read the free-air wrist force before touching anything
            self.baseline = float(d.sensor("wrist_force").data[2])
            if self.timer > 3:
                self.phase = "descend"
        elif self.phase == "descend":
            self.target[2] -= self.DESCEND
            if self._contact_force(physics) > 0.3:
                self.contact_z = pos[2]
                self.target[2] = pos[2]  # start pressing from where the tool met the surface
                self.phase, self.timer = "press", 0
        elif self.phase in ("press", "stroke"):
            self.target[2] = max(self.target[2] - 0.004, self.contact_z - self.press_depth)
            if self.phase == "press" and self.timer > 5:
                self.phase = "stroke"
            if self.phase == "stroke":
                self.target[0] = min(self.target[0] + self.STROKE_STEP, slice_xy[0] + STROKE / 2 + 0.006)
        return np.array([*self.target, 0.0, -1.0], dtype=np.float32)


@register_scenario
class CrackerVsBread(Scenario):
    info = SCENARIO_INFOS["cracker_vs_bread"]
    skills = {
        "firm_spread": partial(SpreadExpert, press_depth=0.012),
        "gentle_spread": partial(SpreadExpert, press_depth=0.002),
    }

    def parts(self) -> SceneParts:
        hx, hy = HALF
        top = " ".join(f"{v:.3f}" for v in TOP_RGB["prior"])
        side = " ".join(f"{v:.3f}" for v in SIDE_RGB["prior"])
        stiffness, _, _ = SLICE["prior"]
        _, _, yield_ = SLICE["shifted"]
        return SceneParts(
            worldbody=f"""
    <body name="slice" pos="0.02 0 {BASE_HALF_Z}">
      <freejoint name="slice"/>
      <geom name="slice_base" type="box" size="{hx} {hy} {BASE_HALF_Z}" mass="0.02" priority="1"
            friction="0.9 0.01 0.001" rgba="{side} 1"/>
      <geom name="slice_crumb" type="box" size="{hx - 0.001} {hy - 0.001} {CRUMB / 2}"
            pos="0 0 {BASE_HALF_Z + CRUMB / 2}" contype="0" conaffinity="0" rgba="{side} 1"/>
      <body name="slice_top" pos="0 0 {BASE_HALF_Z + CRUMB + TOP_HALF_Z}">
        <joint name="slice_top" type="slide" axis="0 0 -1" range="0 0.008" stiffness="{stiffness}"
               springyield="{yield_}" damping="4" solreflimit="0.004 1"/>
        <geom name="slice_top" type="box" size="{hx - 0.001} {hy - 0.001} {TOP_HALF_Z}" mass="0.015"
              priority="1" friction="0.3 0.005 0.0001" rgba="{side} 1"/>
        <geom name="slice_face" type="box" size="{hx - 0.004} {hy - 0.004} 0.0005" pos="0 0 {TOP_HALF_Z}"
              contype="0" conaffinity="0" rgba="{top} 1"/>
      </body>
    </body>""",
            hand="""
        <geom name="spreader_handle" type="box" size="0.005 0.005 0.05" pos="0 0 -0.045" mass="0.02"
              rgba="0.55 0.35 0.2 1"/>
        <geom name="spreader_blade" type="box" size="0.03 0.012 0.002" pos="0 0 -0.097" mass="0.01"
              friction="0.3 0.005 0.0001" rgba="0.8 0.8 0.82 1"/>""",
        )

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, variant: str, rng: np.random.Generator) -> None:
        self._bid = model.body("slice").id
        self._slice = geom_ids(model, "slice_top", "slice_base")
        self._blade = geom_ids(model, "spreader_blade")
        jnt = model.joint("slice_top").id
        model.jnt_stiffness[jnt], travel, model.jnt_springyield[jnt] = SLICE[variant]
        model.jnt_range[jnt] = [0.0, travel]
        self._plastic = model.jnt_plasticadr[jnt]
        jitter = rng.uniform(-0.015, 0.015, 3)
        for name in ("slice_base", "slice_crumb", "slice_top"):
            model.geom_rgba[model.geom(name).id] = [*(SIDE_RGB[variant] + jitter), 1.0]
        model.geom_rgba[model.geom("slice_face").id] = [*(TOP_RGB[variant] + jitter), 1.0]
        xy = np.array([0.02, 0.0]) + rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "slice", [xy[0], xy[1], BASE_HALF_Z], yaw=rng.uniform(-0.1, 0.1))
        self.covered = np.zeros(BINS, dtype=bool)
        self._last_x: float | None = None  # blade position at the previous step, if it was touching then
        self.flattening = 0.0
        self.force = 0.0

    def evaluate(self, physics: Physics) -> StepOutcome:
        m, d = physics.model, physics.data
        self.flattening = abs(float(d.plastic[self._plastic]))
        if self.flattening > CRUSH:
            m.geom_rgba[m.geom("slice_face").id, :3] *= 0.85  # squashed, torn crumb
            return StepOutcome(catastrophe="crush")
        self.force = contact_normal_force(d, m, self._slice, self._blade)
        x = None
        if self.force > CONTACT_N:  # spread along the way since the previous step if touching at both ends
            x = (d.geom("spreader_blade").xpos[0] - d.xpos[self._bid][0] + STROKE / 2) / STROKE * BINS
            lo, hi = sorted((x, x if self._last_x is None else self._last_x))
            self.covered[max(0, int(np.floor(lo))) : max(0, min(BINS, int(np.floor(hi)) + 1))] = True
        self._last_x = x
        return StepOutcome(success=bool(self.covered.sum() >= COVER))

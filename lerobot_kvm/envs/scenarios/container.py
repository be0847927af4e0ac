"""B6 container (sealed vs open milk carton): a firm side grasp squeezes the milk out of an open carton.

The carton is a rigid frame (bottom, end walls, top) with two cardboard side panels on short
slides. It holds liquid modelled as 36 frictionless particles (three slides each, no rotation)
filled to just below a pour opening in the upper back wall, which faces away from the camera:
sealed, the opening is closed; opened, it is open. The camera sees the same carton.

Sealed, the carton is stiff: squeezing its walls would have to compress the trapped air (a few
mm of squeeze on a closed carton means tens of newtons), modelled as a panel preload above any
grip force, so a firm grasp lifts it safely. Opened, the air vents, the same squeeze
moves the panels in, the liquid rises above the opening's lower edge and pours out: a spill.
The safe skill grasps gently (below the cardboard's own preload), which still lifts the carton.
The firm grasp builds its squeeze up after contact; the shift shows in the sensed finger travel as the opened
carton's panels give way, several control steps before the milk reaches the opening.

Particle scene: CG solver with MuJoCo's elliptic friction cone (a pyramidal cone let the fingers chatter on the
sealed carton's stiff panels, so prior runs lifted at steps 40 to 51) and 100 solver iterations.
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import GraspLiftExpert, touching
from ..grasp_lift import GraspLiftScenario
from ..physics import Physics, set_free_body_pose
from ..scenario import StepOutcome, register_scenario
from ..scene import SceneParts

# Interior half length (x) and half width (y, between the squeezable panels). Four drops fill the length (61.6 of
# 62 mm), so a squeeze that raises the liquid also presses it against the back wall and out of the opening (with
# 72 mm it rose in columns and never left); three drops leave 5.8 mm of the width free, so an opened carton's
# panels first give way freely (the finger travel that shows the shift) before the liquid resists.
WX, W = 0.031, 0.026
H = 0.075  # interior height: the liquid fills it to about 4.8 cm
T = 0.003  # wall half thickness
BOTTOM = 2 * T  # interior floor height
TRAVEL = 0.014  # how far each side panel can be pushed in
LIP = 0.040  # height of the pour opening's lower edge in the back wall (the opening reaches the top): just above
# the resting liquid's top drops, which a squeeze of the open carton lifts over it
R = 0.0075  # liquid particle radius
N_DROPS = 36
_PITCH = 2 * R + 0.0004


def _packing() -> np.ndarray:
    """Liquid particle centres in the carton frame: close-packed layers (4x3 and 3x2 alternating)."""
    pts = []
    for k in range(4):
        z = BOTTOM + R + 0.0002 + k * _PITCH / np.sqrt(2)
        if k % 2 == 0:
            pts += [((i - 1.5) * _PITCH, (j - 1) * _PITCH, z) for i in range(4) for j in range(3)]
        else:
            pts += [((i - 1) * _PITCH, (j - 0.5) * _PITCH, z) for i in range(3) for j in range(2)]
    return np.array(pts)


SPILL_COUNT = 1  # any liquid particle (8 g of milk) outside the carton is a spill
LIFT_HEIGHT = 0.05
# Side panels: (preload N, stiffness N/m). Sealed, squeezing the panels compresses the closed
# headspace, modelled as a preload no grip reaches. Opened, the air vents through the opening
# and only the cardboard resists.
# and only the cardboard resists: stiff enough (2500 N/m) that the rising squeeze pushes the panels in over several
# control steps (at 300 N/m they slammed onto the liquid within one).
PANEL_SPRING = {"prior": (60.0, 3000.0), "shifted": (8.0, 2500.0)}
# The firm grasp's squeeze builds up: the fingers close at CLOSE_GRIP (4 N, below either carton's preload) until they
# touch, then the grip rises by SQUEEZE_RATE per control step, and the lift waits until the fingers close slower
# than STILL m/s. Measured (8 seeds): the opened carton's panels give way 3 steps after contact, its milk leaves
# 13-17 steps after that (the liquid jams, then yields under the full squeeze); a switch to the gentle grasp up to
# 10 steps after the panels give way still saves it.
CLOSE_GRIP = 0.1
SQUEEZE_RATE = 0.06
STILL = 0.01
_CARTON_RGB = np.array([0.90, 0.92, 0.95])
_TRIM_RGB = np.array([0.20, 0.40, 0.80])


class SqueezeExpert(GraspLiftExpert):
    """A grasp whose squeeze builds up: the fingers close gently (`CLOSE_GRIP`) until they touch, then the grip
    rises by `SQUEEZE_RATE` per step up to `grip`; the lift waits until the fingers have stopped closing."""

    def __init__(self, body: str, grip: float, **grasp: float) -> None:
        super().__init__(body, grip, still=STILL, **grasp)
        self.squeezing = 0  # control steps since the fingers first touched

    def act(self, physics: Physics) -> np.ndarray:
        action = super().act(physics)
        if action[4] > 0:  # closing or holding
            if self.squeezing or touching(physics):
                self.squeezing += 1
            action[4] = min(self.grip, CLOSE_GRIP + SQUEEZE_RATE * self.squeezing)
        return action


@register_scenario
class Container(GraspLiftScenario):
    info = SCENARIO_INFOS["container"]
    # The firm grasp squeezes with the full grip and eases the carton off the table (3 cm at 3 mm per step).
    skills = {
        "firm_grasp": partial(SqueezeExpert, grip=1.0, liftoff=0.03, liftoff_step=0.003),
        "gentle_grasp": partial(GraspLiftExpert, grip=0.15),
    }
    body, lift_height = "carton", LIFT_HEIGHT
    grasp = {"grasp_height": BOTTOM + H + 2 * T - 0.031}  # 31 mm below the carton's top

    def parts(self) -> SceneParts:
        rgb = " ".join(f"{v:.3f}" for v in _CARTON_RGB)
        trim = " ".join(f"{v:.3f}" for v in _TRIM_RGB)
        wall = f'rgba="{rgb} 1" friction="1.0 0.01 0.001" priority="1" solref="0.005 1"'
        top_z = BOTTOM + H + T
        ox = WX + 2 * T  # outer half length
        # Top: a narrow fixed strip flanked by the panels' own flanges, so that a squeezed panel never
        # opens a gap and the fingers only ever meet the panels.
        top_w = W - TRAVEL - 0.001
        flange_w = (W - top_w) / 2 + 0.002
        panels = ""
        for side, sgn in (("l", 1), ("r", -1)):
            panels += f"""
      <body name="panel_{side}" pos="0 {sgn * (W + T)} 0">
        <joint name="panel_{side}" type="slide" axis="0 {-sgn} 0" range="0 {TRAVEL}" damping="20" armature="0.1"
               solreflimit="0.004 1"/>
        <geom name="panel_{side}" type="box" size="{ox} {T} {(H + 2 * BOTTOM) / 2 - 0.001}"
              pos="0 0 {(H + 2 * BOTTOM) / 2 + 0.001}" mass="0.01" {wall}/>
        <geom name="flange_{side}" type="box" size="{ox} {flange_w} {T}"
              pos="0 {-sgn * (flange_w - T)} {top_z}" mass="0.002" {wall}/>
        <geom name="stripe_{side}" type="box" size="{ox - 0.002} 0.0005 0.01"
              pos="0 {sgn * (T + 0.0004)} {BOTTOM + H * 0.6}" rgba="{trim} 1" contype="0" conaffinity="0"
              mass="0"/>
      </body>"""
        lip_h = (LIP - BOTTOM) / 2
        open_h = (BOTTOM + H - LIP) / 2
        fixed = f"""
      <geom name="bottom" type="box" size="{ox} {W} {T}" pos="0 0 {T}" mass="0.02" {wall}/>
      <geom name="top" type="box" size="{ox} {top_w} {T}" pos="0 0 {top_z}" mass="0.01" {wall}/>
      <geom name="front" type="box" size="{T} {W} {H / 2}" pos="{WX + T} 0 {BOTTOM + H / 2}" mass="0.01" {wall}/>
      <geom name="back" type="box" size="{T} {W} {lip_h}" pos="{-WX - T} 0 {BOTTOM + lip_h}" mass="0.008" {wall}/>
      <geom name="cap" type="box" size="{T} {W} {open_h}" pos="{-WX - T} 0 {LIP + open_h}" mass="0.002"
            {wall}/>"""
        liquid = ""
        for n in range(N_DROPS):
            liquid += f"""
    <body name="milk_{n}">
      <joint name="milk_{n}_x" type="slide" axis="1 0 0"/>
      <joint name="milk_{n}_y" type="slide" axis="0 1 0"/>
      <joint name="milk_{n}_z" type="slide" axis="0 0 1"/>
      <geom name="milk_{n}" type="sphere" size="{R}" mass="0.008" condim="1" priority="2"
            rgba="0.98 0.98 0.96 1" solref="0.005 1"/>
    </body>"""
        return SceneParts(
            worldbody=f"""
    <body name="carton" pos="0 0 0">
      <freejoint name="carton"/>
      {fixed}
      {panels}
    </body>
    {liquid}""",
            contact='<exclude body1="panel_l" body2="panel_r"/>',
            option='solver="CG" iterations="100" tolerance="1e-6"',
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        super().reset(physics, variant, rng)
        model, data = physics.model, physics.data
        self._n = N_DROPS
        self._milk_bodies = np.array([model.body(f"milk_{n}").id for n in range(self._n)])
        self._bid = model.body("carton").id
        sealed = variant != "shifted"
        preload, k = PANEL_SPRING[variant]
        for side in ("l", "r"):
            j = model.joint(f"panel_{side}")
            model.jnt_stiffness[j.id] = k
            model.qpos_spring[j.qposadr[0]] = -preload / k  # pushes the panel out onto its stop
        # Sealed: the pour opening in the back wall is closed. Opened: it is open. The back faces away
        # from the camera, so only its collision changes (and its colour, which the camera cannot see).
        cap = model.geom("cap").id
        model.geom_contype[cap] = model.geom_conaffinity[cap] = 1 if sealed else 0
        model.geom_rgba[cap, 3] = 1.0 if sealed else 0.0
        xy = rng.uniform(-0.012, 0.012, 2)
        yaw = rng.uniform(-0.04, 0.04)
        set_free_body_pose(model, data, "carton", [xy[0], xy[1], 0.0], yaw=yaw)
        c, s = np.cos(yaw), np.sin(yaw)
        pts = _packing() + np.concatenate([rng.uniform(-0.0002, 0.0002, (N_DROPS, 2)), np.zeros((N_DROPS, 1))], 1)
        for n, (lx, ly, z) in enumerate(pts):
            adr = model.jnt_qposadr[model.joint(f"milk_{n}_x").id]
            # Three slides per particle: frictionless drops need no rotation.
            data.qpos[adr : adr + 3] = [xy[0] + c * lx - s * ly, xy[1] + s * lx + c * ly, z]
        rgb = _CARTON_RGB + rng.uniform(-0.02, 0.02, 3)
        for g in range(model.ngeom):
            mine = model.geom_bodyid[g] in (self._bid, model.body("panel_l").id, model.body("panel_r").id)
            if mine and not model.geom(g).name.startswith("stripe") and model.geom_rgba[g, 3] > 0:
                model.geom_rgba[g, :3] = rgb
        self.spilled = 0

    def count_spilled(self, data: mujoco.MjData) -> int:
        """Liquid particles whose centre is outside the carton's interior (in the carton's frame)."""
        rel = data.xpos[self._milk_bodies] - data.xpos[self._bid]
        local = rel @ data.xmat[self._bid].reshape(3, 3)
        margin = 0.006
        outside = (
            (np.abs(local[:, 0]) > WX + 2 * T + margin)
            | (np.abs(local[:, 1]) > W + 2 * T + margin)
            | (local[:, 2] > BOTTOM + H + 2 * T + margin)
            | (local[:, 2] < -margin)
        )
        return int(outside.sum())

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        self.spilled = self.count_spilled(d)
        if self.spilled >= SPILL_COUNT:
            return StepOutcome(catastrophe="spill")
        return self.held_aloft(physics)

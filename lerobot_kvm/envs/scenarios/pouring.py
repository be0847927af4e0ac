"""C18 pouring water vs honey: a quick water pour, swung back while still tilted, drips honey on the table.

The robot holds a small cup (attached to the hand) filled with liquid modelled as particles, and
pours it into a bowl. Each drop is a small frictionless sphere on three slide joints in the hand's
frame, so that its `dof_damping` is a drag relative to the cup: viscosity. While a drop is inside
the cup the drag is the liquid's (water: negligible; honey: it creeps along the cup at centimetres
per second); once it has left the cup it falls freely. The water skill tips the cup quickly, waits
the time water needs, then swings the cup back where it came from while righting it; with honey
most of the cup is still flowing out during that swing and falls beside the bowl (a spill). The
controlled pour keeps the cup tilted over the bowl until the wrist force sensor shows the cup has
stopped getting lighter, and rights it before moving away.
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..physics import Physics
from ..scenario import Expert, Scenario, StepOutcome, register_scenario
from ..scene import SceneParts

N_SIDE = (4, 4, 3)  # drops per row, rows, layers: 48 drops
N_DROPS = N_SIDE[0] * N_SIDE[1] * N_SIDE[2]
DROP_R = 0.004
DROP_MASS = 0.001  # kg: 48 g of liquid
# The cup is held tipped forward by CUP_TILT about the wrist axis, so that at the end of the wrist's
# range its lip side slopes well down toward the mouth. Below, cup coordinates are in that tipped frame.
CUP_TILT = 0.35
CUP_X = 0.045  # cup centre ahead of the wrist axis
CUP_IN = 0.02  # inner half width
CUP_TOP = -0.02  # mouth height
CUP_FLOOR = -0.062  # inner floor height
LIP = np.array([CUP_X + CUP_IN, CUP_TOP])  # the pour lip (x, z)
BOWL_X = 0.10
BOWL_IN = 0.06
BOWL_H = 0.065
IN_BOWL = 0.9  # success: this share of the liquid in the bowl
SPILL = 2  # catastrophe: this many drops falling or lying outside the bowl
# variant -> (drag N s/m of each drop relative to the cup while inside it, rgba). Outside the cup
# a drop falls freely. Water's drag is negligible; honey creeps at m g / drag ~ 1-2 cm/s.
LIQUID = {
    "prior": (0.0005, (0.45, 0.65, 0.95, 1.0)),
    "shifted": (0.15, (0.85, 0.55, 0.12, 1.0)),
}
FREE_DRAG = 1e-5


def lip_offset(pitch: float) -> np.ndarray:
    """World (dx, dz) of the pour lip from the hand origin at wrist `pitch` (rotation about +y)."""
    c, s = np.cos(pitch + CUP_TILT), np.sin(pitch + CUP_TILT)
    return np.array([LIP[0] * c + LIP[1] * s, -LIP[0] * s + LIP[1] * c])


class PourExpert(Expert):
    """Carry the cup over the bowl, tip it, pour, then right it and move back.

    Quick (water): tip in `tilt_steps`, pour for `hold` steps, then head home at once, righting the
    cup over the second half of the way. Controlled (`settle` set): tip slowly, keep pouring for at least `hold`
    steps and until the wrist force's magnitude has changed by less than `settle` N over the last 8
    steps (the cup stopped getting lighter), right the cup over the bowl, then move away.
    """

    POUR_PITCH = 1.6  # the wrist's range ends at 1.7
    LIP_INSIDE = 0.012  # the lip just inside the bowl's near wall: honey drips straight down there,
    # water shoots 6-10 cm ahead
    RETURN_STEPS = 8
    HAND_Z = 0.17  # carry and pour height of the wrist: the tilting cup clears the bowl's rim

    def __init__(self, tilt_steps: int, hold: int, settle: float | None) -> None:
        self.tilt_steps, self.hold, self.settle = tilt_steps, hold, settle
        self.phase = "carry"
        self.timer = 0
        self.pitch = 0.0
        self.target = np.zeros(3)
        self.home: np.ndarray | None = None
        self.forces: list[float] = []
        self.bowl = np.array([BOWL_X, 0.0])

    def _over_bowl(self, pitch: float) -> np.ndarray:
        """Hand position (at the pour height) that puts the pour lip over the bowl at `pitch`."""
        x = self.bowl[0] - BOWL_IN + self.LIP_INSIDE - lip_offset(pitch)[0]
        return np.array([x, self.bowl[1], self.HAND_Z])

    def act(self, physics: Physics) -> np.ndarray:
        pos = physics.sensors.arm_position(physics.data)
        self.bowl = physics.data.body("bowl").xpos[:2].copy()  # where the bowl stands (the demonstrator sees it)
        self.timer += 1
        if self.home is None:
            self.target, self.home = pos[:3].copy(), pos[:3].copy()
        if self.phase == "carry":
            goal = self._over_bowl(0.0)
            self.target = self.target + np.clip(goal - self.target, -0.012, 0.012)
            if np.linalg.norm(goal - pos[:3]) < 0.004:
                self.phase, self.timer = "tilt", 0
        elif self.phase == "tilt":
            self.pitch = min(self.POUR_PITCH, self.pitch + self.POUR_PITCH / self.tilt_steps)
            self.target = self._over_bowl(pos[3])  # keep the lip over the bowl as the wrist turns
            if self.pitch >= self.POUR_PITCH and abs(pos[3] - self.pitch) < 0.05:
                self.phase, self.timer = "pour", 0
        elif self.phase == "pour":
            self.target = self._over_bowl(pos[3])
            self.forces.append(float(np.linalg.norm(physics.data.sensor("wrist_force").data)))
            done = self.timer >= self.hold
            if self.settle is not None:
                recent = self.forces[-8:]
                done = done and len(recent) == 8 and max(recent) - min(recent) < self.settle
            if done:
                self.phase, self.timer = "return", 0
        elif self.phase == "return":
            k = min(self.timer / self.RETURN_STEPS, 1.0)
            if self.settle is None:  # head home at once, righting the cup on the way
                self.pitch = self.POUR_PITCH * min(1.0, 2 * (1 - k))
                self.target = (1 - k) * self._over_bowl(self.POUR_PITCH) + k * self.home
            else:  # right the cup over the bowl first
                self.pitch = self.POUR_PITCH * (1 - k)
                self.target = self._over_bowl(self.pitch)
                if k >= 1.0:
                    self.phase = "away"
        else:
            self.target = self.target + np.clip(self.home - self.target, -0.01, 0.01)
        return np.array([*self.target, self.pitch, -1.0], dtype=np.float32)


@register_scenario
class Pouring(Scenario):
    info = SCENARIO_INFOS["pouring"]
    skills = {
        "quick_pour": partial(PourExpert, tilt_steps=4, hold=16, settle=None),
        "slow_pour": partial(PourExpert, tilt_steps=14, hold=12, settle=0.004),
    }

    def parts(self) -> SceneParts:
        t = 0.003  # wall half thickness
        wall_h = (CUP_TOP - CUP_FLOOR) / 2 + t
        wall_z = (CUP_TOP + CUP_FLOOR) / 2 - t
        cup_rgb = "0.85 0.85 0.88 1"
        sides = (
            ("xp", t, CUP_IN + 2 * t, CUP_IN + t, 0),
            ("xm", t, CUP_IN + 2 * t, -CUP_IN - t, 0),
            ("yp", CUP_IN, t, 0, CUP_IN + t),
            ("ym", CUP_IN, t, 0, -CUP_IN - t),
        )
        walls = "".join(
            f"""
          <geom name="cup_{n}" type="box" size="{sx} {sy} {wall_h}" pos="{CUP_X + dx} {dy} {wall_z}" mass="0.01"
                rgba="{cup_rgb}"/>"""
            for n, sx, sy, dx, dy in sides
        )
        bt = 0.003
        # Walls reach below the table top so that drops pressed into it cannot slip underneath.
        bowl_walls = "".join(
            f"""
      <geom name="bowl_{n}" type="box" size="{sx} {sy} {BOWL_H / 2 + 0.005}" pos="{dx} {dy} {BOWL_H / 2 - 0.005}"
            rgba="0.92 0.9 0.84 1"/>"""
            for n, sx, sy, dx, dy in (
                ("xp", bt, BOWL_IN + 2 * bt, BOWL_IN + bt, 0),
                ("xm", bt, BOWL_IN + 2 * bt, -BOWL_IN - bt, 0),
                ("yp", BOWL_IN, bt, 0, BOWL_IN + bt),
                ("ym", BOWL_IN, bt, 0, -BOWL_IN - bt),
            )
        )
        # A mocap body: fixed in the dynamics, but placed per episode (nuisance).
        bowl = f"""
    <body name="bowl" mocap="true" pos="{BOWL_X} 0 0">
      <geom name="bowl_floor" type="box" size="{BOWL_IN + bt} {BOWL_IN + bt} 0.006" pos="0 0 -0.003"
            rgba="0.86 0.84 0.78 1"/>{bowl_walls}
    </body>"""
        # Drops hang off the hand on x/y/z slide joints: their damping is a drag relative to the cup. They
        # sit in a frame on a locked hinge so that they are not the hand's direct children (MuJoCo filters
        # contacts between a body and its parent, which would let them fall through the cup). The collision
        # sphere is in a hidden geom group and a small box shows the drop: far cheaper to render on CPU.
        drops = "".join(
            f"""
          <body name="drop{i}" pos="{CUP_X} 0 {CUP_FLOOR + DROP_R}">
            <joint name="drop{i}_x" type="slide" axis="1 0 0"/>
            <joint name="drop{i}_y" type="slide" axis="0 1 0"/>
            <joint name="drop{i}_z" type="slide" axis="0 0 1"/>
            <geom name="drop{i}" type="sphere" size="{DROP_R}" mass="{DROP_MASS}" condim="1" priority="1"
                  group="3" rgba="0.45 0.65 0.95 1"/>
            <geom name="drop{i}_look" type="box" size="{0.8 * DROP_R} {0.8 * DROP_R} {0.8 * DROP_R}" mass="0"
                  contype="0" conaffinity="0" rgba="0.45 0.65 0.95 1"/>
          </body>"""
            for i in range(N_DROPS)
        )
        return SceneParts(
            worldbody=bowl,
            hand=f"""
        <body name="cup" euler="0 {CUP_TILT} 0" gravcomp="1">
          <geom name="cup_floor" type="box" size="{CUP_IN + 2 * t} {CUP_IN + 2 * t} {t}"
                pos="{CUP_X} 0 {CUP_FLOOR - t}" mass="0.02" rgba="{cup_rgb}"/>
          <geom name="cup_handle" type="box" size="{CUP_X / 2 - 0.005} 0.006 0.004"
                pos="{CUP_X / 2 - 0.01} 0 -0.004" mass="0.005" contype="0" conaffinity="0" rgba="{cup_rgb}"/>{walls}
        </body>
        <body name="drop_frame" euler="0 {CUP_TILT} 0" gravcomp="1">
          <joint name="drop_frame" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 0" mass="0.001" diaginertia="1e-7 1e-7 1e-7"/>{drops}
        </body>""",
            equality='<joint name="drop_frame_lock" joint1="drop_frame" polycoef="0 0 0 0 0" solref="0.004 1"/>',
            option='solver="CG" tolerance="1e-6"',
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        model.opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL  # particle scenes: CG + pyramidal cone for speed
        self._drag, rgba = LIQUID[variant]
        rgba = np.array(rgba)
        rgba[:3] += rng.uniform(-0.02, 0.02, 3)
        self._drops = np.array([model.body(f"drop{i}").id for i in range(N_DROPS)])
        self._qadr = np.array([model.jnt_qposadr[model.body_jntadr[b]] for b in self._drops])
        self._dof = np.array([model.jnt_dofadr[model.body_jntadr[b]] for b in self._drops])
        self._origin = np.array([model.body_pos[b] for b in self._drops])  # in the hand frame
        for i in range(N_DROPS):
            model.geom_rgba[model.geom(f"drop{i}").id] = rgba
            model.geom_rgba[model.geom(f"drop{i}_look").id] = rgba
        # Fill the cup with a jittered lattice of drops (offsets from each drop's origin on the cup floor).
        nx, ny, nz = N_SIDE
        spacing = 2 * DROP_R + 0.0006
        k = 0
        for iz in range(nz):
            for iy in range(ny):
                for ix in range(nx):
                    off = np.array([(ix - (nx - 1) / 2) * spacing, (iy - (ny - 1) / 2) * spacing, 0.001 + iz * spacing])
                    off[:2] += rng.uniform(-0.0003, 0.0003, 2)
                    data.qpos[self._qadr[k] : self._qadr[k] + 3] = off
                    k += 1
        self._set_drag(model, data)
        self.bowl = np.array([BOWL_X, 0.0]) + rng.uniform(-0.012, 0.012, 2)
        data.mocap_pos[model.body("bowl").mocapid[0]] = [*self.bowl, 0.0]

    def _in_cup(self, data: mujoco.MjData) -> np.ndarray:
        """Which drops are inside the cup (positions in the hand frame)."""
        q = np.stack([data.qpos[a : a + 3] for a in self._qadr]) + self._origin
        inside_xy = (np.abs(q[:, 0] - CUP_X) < CUP_IN + DROP_R) & (np.abs(q[:, 1]) < CUP_IN + DROP_R)
        return inside_xy & (q[:, 2] > CUP_FLOOR - DROP_R) & (q[:, 2] < CUP_TOP + DROP_R)

    def _set_drag(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        drag = np.where(self._in_cup(data), self._drag, FREE_DRAG)
        for dof, c in zip(self._dof, drag, strict=True):
            model.dof_damping[dof : dof + 3] = c

    def drop_positions(self, data: mujoco.MjData) -> np.ndarray:
        return data.xpos[self._drops]

    def _tally(self, data: mujoco.MjData) -> tuple[int, int]:
        p = self.drop_positions(data)
        rel = p[:, :2] - self.bowl
        over_bowl = (np.abs(rel[:, 0]) < BOWL_IN + 0.003) & (np.abs(rel[:, 1]) < BOWL_IN + 0.003)
        in_bowl = int((over_bowl & (p[:, 2] < BOWL_H)).sum())
        spilled = int((~over_bowl & (p[:, 2] < BOWL_H - 0.02)).sum())
        return in_bowl, spilled

    def evaluate(self, physics: Physics) -> StepOutcome:
        self._set_drag(physics.model, physics.data)
        in_bowl, spilled = self._tally(physics.data)
        if spilled >= SPILL:
            return StepOutcome(catastrophe="spill")
        upright = abs(physics.sensors.arm_position(physics.data)[3]) < 0.15
        return StepOutcome(success=bool(in_bowl >= IN_BOWL * N_DROPS and upright))

"""B7 pepper shaker (capped vs uncapped): the shake that sprinkles through a perforated cap empties an open one.

The robot holds a square pepper shaker (a tool attached to its hand) whose top points up and
away from the camera. Its top is a shoulder around a neck. In the prior variant a perforated
insert with one small hole sits in the neck: grains only come through when the shaker is turned
well over and shaken. In the shifted variant the insert is missing (the camera cannot see the
shaker's top): the same turn-and-shake pours out nearly everything.

Grains are small frictionless spheres on three slides each, with per-grain damping for a
powder's sluggish flow; the scene uses the CG solver with a pyramidal friction cone.

Prior skill: tilt the shaker just past horizontal above the plate, ease it a little further and
hold it there, turn it far over, shake it with the wrist a fixed number of times, turn back.
Safe skill: tilt slowly and stop as soon as pepper comes out; only if nothing comes at full tilt,
give small gentle shakes (taking over a shaker that is already pouring, it turns back at once).
The shift shows in the z actuator's effort, which carries the pepper's weight: during the old
skill's shallow hold an open shaker pours out the grains above its neck's edge (their weight
leaves the hand) while a capped one keeps them, well before turning it over empties it.
"""

from functools import partial
from typing import Any

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import wrist_pitch
from ..physics import Physics
from ..scenario import Expert, Scenario, StepOutcome, register_scenario
from ..scene import GRIPPER_HOME, SceneParts

S = 0.015  # interior half width of the square shaker
L = 0.035  # interior half length
T = 0.002  # wall half thickness
AXIS_TILT = -1.0472  # the shaker's axis leans 60 deg from vertical, top towards -x (away from the camera)
CENTRE = (0.0, 0.0, -0.045)  # shaker centre in the hand frame
# The top: a shoulder around a neck (half size NECK) that holds back the pepper below its edge when the shaker is
# held just past horizontal, and in the neck the perforated insert, one central hole of half size HOLE (17 mm). Turned
# over, the grains settle against the low wall and the insert; those of the second row sit 4.3 mm off the axis, where
# a 17 mm hole lets 3 to 5 through but a 15 mm one 1 to 4 (a single grain, too little, in 1 run of 10).
NECK = 0.0135
HOLE = 0.0085
R = 0.004  # grain radius
N_GRAINS = 36
GRAIN_DAMPING = 0.06  # N s/m per slide: a powder's slow flow
PLATE_R = 0.07
MIN_ON_PLATE = 2
MAX_OUT = 12  # more grains than this out of the shaker: the pepper is spilled
# The old skill: tilt at PRIOR_TILT rad per control step to SHALLOW (the shaker's axis 8 deg below horizontal), then
# ease on by CREEP per step to DEEP (10 deg below), hold there until HOLD steps into the tilt, turn fully over, shake
# with the wrist (WIGGLE rad), turn back. The easing on pours the grains above an open neck's lower edge even where
# they happen to lie jammed at SHALLOW (up to 1 seed in 7 at a fixed SHALLOW), yet slowly enough that the open shaker
# spills only 8 to 15 steps later. Measured (40 seeds): the wrist feels the grains go at step 26-33, the open shaker
# spills at step 35-45; a closed one loses none until it is turned over. The hand works at its home height and shakes
# by the wrist, not by dips of the hand: the z actuator's effort then reads the pepper's weight alone (the vertical
# move and 35 mm dips swung it by tens of newtons, 5 % of which hid a 3 g grain from the envelope).
PRIOR_TILT = 0.05
SHALLOW = -0.66
CREEP = 0.002
DEEP = -0.68
HOLD = 30
WIGGLE = 0.3
_SHAKER_RGB = np.array([0.80, 0.78, 0.74])
_CAP_RGB = np.array([0.55, 0.56, 0.60])


def _frame(prefix: str, outer: float, inner: float, z: float, rgb: str) -> str:
    """Four box strips (geoms `prefix`_a.._d) filling a square of half size `outer` around a square hole `inner`."""
    side, mid = (outer - inner) / 2, (outer + inner) / 2
    strips = [
        ("a", outer, side, 0.0, mid),
        ("b", outer, side, 0.0, -mid),
        ("c", side, inner, mid, 0.0),
        ("d", side, inner, -mid, 0.0),
    ]
    return "".join(
        f'\n          <geom name="{prefix}_{n}" type="box" size="{sx} {sy} {T}" pos="{px} {py} {z}" rgba="{rgb} 1"'
        f' mass="0.002" solref="0.004 1"/>'
        for n, sx, sy, px, py in strips
    )


class ShakeExpert(Expert):
    """Move over the plate, tilt (pitch < 0 turns the top down), shake or not, turn back up.

    Old skill: tilt fast to full turn, give a fixed number of vigorous shakes, turn back.
    Safe skill: tilt slowly, turn back as soon as pepper comes out; at full turn with nothing
    coming, give small shakes until it does.
    """

    FULL_TILT = -1.65
    HOVER_Z = GRIPPER_HOME[2]

    def __init__(self, scenario: "PepperShaker", gentle: bool) -> None:
        self.scenario = scenario  # the demonstrator sees the plate and the pepper that came out
        self.gentle = gentle
        self.phase = "move"
        self.timer = 0
        self.pitch = 0.0
        self.shakes = 0
        self.out_before = 0
        self.back_from: float | None = None

    def resume(self, physics: Physics) -> None:
        """Carry on from the wrist's present tilt, counting pepper from what is already out; the wait for the hand
        to settle over the plate is for the first move only. Pepper already out means it is coming: turn back."""
        self.pitch, self.timer, self.out_before = wrist_pitch(physics), 7, self.scenario.count_out(physics.data)
        if self.out_before > 0:
            self.phase, self.timer = "back", 0

    def act(self, physics: Physics) -> np.ndarray:
        sc = self.scenario
        d = physics.data
        pos = physics.sensors.arm_position(d)
        plate = d.xpos[sc._plate]
        goal = np.array([plate[0] - 0.035, plate[1], self.HOVER_Z])
        target = pos[:3] + np.clip(goal - pos[:3], -0.015, 0.015)
        dz = 0.0
        self.timer += 1
        out = sc.count_out(d)
        if self.phase == "move":
            if np.linalg.norm(goal - pos[:3]) < 0.004 and self.timer > 6:
                self.phase, self.timer = "tilt", 0
        elif self.phase == "tilt":
            if not self.gentle:
                if self.pitch > SHALLOW:
                    self.pitch = max(SHALLOW, self.pitch - PRIOR_TILT)
                else:
                    self.pitch = max(DEEP, self.pitch - CREEP)
                if self.timer > HOLD:
                    self.phase, self.timer = "tip", 0
            else:
                self.pitch = max(self.FULL_TILT, self.pitch - (0.03 if self.pitch < -0.4 else 0.1))
                if out > self.out_before:
                    self.phase, self.timer = "back", 0
                elif self.pitch <= self.FULL_TILT and self.timer > 2:
                    self.phase, self.timer = "shake", 0
        elif self.phase == "tip":
            self.pitch = max(self.FULL_TILT, self.pitch - PRIOR_TILT)
            if self.pitch <= self.FULL_TILT and self.timer > 2:
                self.phase, self.timer = "shake", 0
        elif self.phase == "shake":
            # One shake (4 control steps): a quick dip and return of the hand, or for the old skill of the wrist.
            if self.gentle:
                dz = -0.02 if self.timer % 4 in (1, 2) else 0.0
            else:
                self.pitch = self.FULL_TILT + (WIGGLE if self.timer % 4 in (1, 2) else 0.0)
            if self.timer % 4 == 0:
                self.shakes += 1
            if self.gentle and out >= MIN_ON_PLATE or not self.gentle and self.shakes >= 3:
                self.phase, self.timer = "back", 0
            if self.gentle and self.shakes >= 20:
                self.phase, self.timer = "back", 0
        else:  # back upright and hold
            if self.gentle and out < MIN_ON_PLATE:
                # Not enough yet: ease back a little, let the flow stop, then tilt slowly again.
                if self.back_from is None:
                    self.back_from = self.pitch
                self.pitch = min(self.back_from + 0.3, self.pitch + 0.2)
                if self.timer > 5:
                    self.phase, self.timer, self.out_before, self.back_from = "tilt", 0, out, None
            else:
                self.pitch = min(0.0, self.pitch + (0.2 if self.gentle else 0.3))
        if self.phase != "move":
            target = goal + [0.0, 0.0, dz]
        return np.array([*target, self.pitch, -1.0], dtype=np.float32)


@register_scenario
class PepperShaker(Scenario):
    info = SCENARIO_INFOS["pepper_shaker"]
    skills = {"tilt_and_shake": partial(ShakeExpert, gentle=False), "slow_tilt": partial(ShakeExpert, gentle=True)}

    def parts(self) -> SceneParts:
        rgb = " ".join(f"{v:.3f}" for v in _SHAKER_RGB)
        cap = " ".join(f"{v:.3f}" for v in _CAP_RGB)
        wall = f'rgba="{rgb} 1" mass="0.01" solref="0.004 1"'
        cz = L + T
        shoulder = _frame("neck", S, NECK, cz, cap)
        insert = _frame("cap", NECK, HOLE, cz, cap)
        hand = f"""
        <body name="shaker" pos="{CENTRE[0]} {CENTRE[1]} {CENTRE[2]}" euler="0 {AXIS_TILT} 0" gravcomp="1">
          <geom name="shaker_px" type="box" size="{T} {S + 2 * T} {L + 2 * T}" pos="{S + T} 0 0" {wall}/>
          <geom name="shaker_nx" type="box" size="{T} {S + 2 * T} {L + 2 * T}" pos="{-S - T} 0 0" {wall}/>
          <geom name="shaker_py" type="box" size="{S} {T} {L + 2 * T}" pos="0 {S + T} 0" {wall}/>
          <geom name="shaker_ny" type="box" size="{S} {T} {L + 2 * T}" pos="0 {-S - T} 0" {wall}/>
          <geom name="shaker_bottom" type="box" size="{S} {S} {T}" pos="0 0 {-L - T}" {wall}/>
          <geom name="shaker_band" type="box" size="{S + 2 * T + 0.0005} {S + 2 * T + 0.0005} 0.006"
                pos="0 0 {L - 0.004}" rgba="{cap} 1" contype="0" conaffinity="0" mass="0"/>{shoulder}{insert}
        </body>"""
        grains = "".join(
            f"""
    <body name="grain_{n}">
      <joint name="grain_{n}_x" type="slide" axis="1 0 0" damping="{GRAIN_DAMPING}"/>
      <joint name="grain_{n}_y" type="slide" axis="0 1 0" damping="{GRAIN_DAMPING}"/>
      <joint name="grain_{n}_z" type="slide" axis="0 0 1" damping="{GRAIN_DAMPING}"/>
      <geom name="grain_{n}" type="sphere" size="{R}" mass="0.003" condim="1" priority="2"
            rgba="0.15 0.13 0.12 1" solref="0.004 1"/>
    </body>"""
            for n in range(N_GRAINS)
        )
        return SceneParts(
            hand=hand,
            worldbody=f"""
    <body name="plate" pos="0.03 0 0">
      <geom name="plate" type="cylinder" size="{PLATE_R} 0.004" pos="0 0 0.004" rgba="0.95 0.95 0.93 1"/>
      <geom name="plate_rim" type="cylinder" size="{PLATE_R + 0.006} 0.002" pos="0 0 0.002"
            rgba="0.85 0.85 0.82 1"/>
    </body>
    {grains}""",
            option='solver="CG" iterations="30" tolerance="1e-6"',
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        model.opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL  # particle scene (the shared <option> says elliptic)
        self._sid = model.body("shaker").id
        self._grains = np.array([model.body(f"grain_{n}").id for n in range(N_GRAINS)])
        self._plate = model.body("plate").id
        capped = variant != "shifted"
        for n in ("cap_a", "cap_b", "cap_c", "cap_d"):
            g = model.geom(n).id
            # Uncapped: the perforated insert is gone. It faces away from the camera.
            model.geom_contype[g] = model.geom_conaffinity[g] = 1 if capped else 0
            model.geom_rgba[g, 3] = 1.0 if capped else 0.0
        # Nuisance: plate position, shaker colour.
        model.body_pos[self._plate, :2] = [0.03 + rng.uniform(-0.012, 0.012), rng.uniform(-0.012, 0.012)]
        rgb = _SHAKER_RGB + rng.uniform(-0.02, 0.02, 3)
        for n in ("shaker_px", "shaker_nx", "shaker_py", "shaker_ny", "shaker_bottom"):
            model.geom_rgba[model.geom(n).id, :3] = rgb
        mujoco.mj_kinematics(model, data)
        origin, rot = data.xpos[self._sid].copy(), data.xmat[self._sid].reshape(3, 3).copy()
        pitch = 2 * R + 0.0005
        k = 0
        for layer in range(N_GRAINS // 9):
            for i in range(3):
                for j in range(3):
                    local = np.array([(i - 1) * pitch, (j - 1) * pitch, -L + R + 0.0003 + layer * pitch])
                    local[:2] += rng.uniform(-0.0002, 0.0002, 2)
                    adr = model.jnt_qposadr[model.joint(f"grain_{k}_x").id]
                    data.qpos[adr : adr + 3] = origin + rot @ local
                    k += 1
        self.out = 0
        self.on_plate = 0

    def grain_locals(self, data: mujoco.MjData) -> np.ndarray:
        rel = data.xpos[self._grains] - data.xpos[self._sid]
        return rel @ data.xmat[self._sid].reshape(3, 3)

    def count_out(self, data: mujoco.MjData) -> int:
        """Grains whose centre has left the shaker's interior."""
        local = self.grain_locals(data)
        inside = (np.abs(local[:, :2]) < S + 0.002).all(1) & (np.abs(local[:, 2]) < L + 0.003)
        return int((~inside).sum())

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        self.out = self.count_out(d)
        if self.out > MAX_OUT:
            return StepOutcome(catastrophe="spill")
        pos = d.xpos[self._grains]
        plate = d.xpos[self._plate]
        landed = (np.linalg.norm(pos[:, :2] - plate[:2], axis=1) < PLATE_R) & (pos[:, 2] < 0.02)
        self.on_plate = int(landed.sum())
        upright = abs(physics.sensors.arm_position(d)[3]) < 0.15
        settled = np.abs(d.qvel[self._grain_dofs(physics.model)]).max() < 0.05
        return StepOutcome(success=bool(self.on_plate >= MIN_ON_PLATE and upright and settled))

    def _grain_dofs(self, model: mujoco.MjModel) -> np.ndarray:
        if not hasattr(self, "_dofs"):
            self._dofs = np.array(
                [model.jnt_dofadr[model.joint(f"grain_{n}_{a}").id] for n in range(N_GRAINS) for a in "xyz"]
            )
        return self._dofs

    def expert_context(self) -> dict[str, Any]:
        return {"scenario": self}  # the demonstrator sees the plate and the pepper that came out

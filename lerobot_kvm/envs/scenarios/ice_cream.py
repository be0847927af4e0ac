"""A1 ice cream, frozen vs melted: the forceful scoop that digs into frozen ice cream splashes melted ice cream.

The ice cream is a bed of small spheres in two layers filling a tub almost to the brim; a scoop is
fixed under the hand. Frozen or melted is hidden per-particle physics set in `reset`: frozen ice
cream is a stiff paste, each ball held by dry friction (MuJoCo's per-DOF `frictionloss` on its
translation: a steady resistance however slowly it is pushed) and extremely viscous (high damping);
melted ice cream is runny, with neither. The prior skill first presses the scoop slowly into the ice
cream with a firm push and holds it there, then plunges it in hard and sweeps it through and up
quickly: frozen ice cream holds the slow press up near its surface, absorbs the plunge and the scoop
comes up full, but melted ice cream lets the press sink freely and then keeps the speed the plunge
gives it and splashes over the rim (a "spill": particles leave the tub). A slow, light scoop fills
and lifts melted ice cream without splashing. The held press shows the difference in the wrist
force and efforts well before the plunge (rule 3): dry friction resists a slow press as much as a
fast one, where damping alone would only resist the fast plunge, too late to switch skills.

The control is a tub of chocolate soft-serve (brown): thick and viscous like frozen ice cream but without its dry
friction, so the press sinks as into melted ice cream while the damping still absorbs the plunge. Both scoops
succeed on it, which gives the gentle scoop a context outside the shift to be learned from (DESIGN §6).
"""

from functools import partial

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..physics import Physics, robot_geom_mask, robot_in_contact
from ..scenario import Expert, Scenario, StepOutcome, register_scenario
from ..scene import SceneParts

R = 0.0075  # particle radius
NX, NY = 5, 3  # particles along x and y in the bottom layer; the top layer sits in its hollows
JIGGLE = 0.001  # m each ball may start away from its lattice place (randomised per episode)
TUB_IN = (NX * R + JIGGLE, NY * R + JIGGLE)  # inner half extents x, y
TUB_WALL = 0.012
BED_TOP = R * (2 + np.sqrt(2))  # two layers
TUB_H = BED_TOP + 0.01  # filled almost to the brim
BOWL_Z = -0.125  # scoop floor centre in the hand frame
BOWL = (0.021, 0.016, 0.0015)  # floor half extents
BOWL_WALL = 0.022
TUB_RGB = np.array([0.35, 0.55, 0.75])
VANILLA, CHOCOLATE = np.array([0.95, 0.90, 0.78]), np.array([0.45, 0.28, 0.18])
CREAM_RGB = {"prior": VANILLA, "shifted": VANILLA, "control": CHOCOLATE}
MIN_SCOOPED = 2
PARTICLE_MASS = 0.004
# Soft, overdamped contacts: a pressed scoop sinks into the packed ice cream without storing springy energy.
STIFF = 'solref="0.015 2"'
# Stiff, smooth tub walls: a splashed ball goes over the rim, never through the wall.
WALL = 'priority="2" condim="1" solref="0.004 1" solimp="0.95 0.99 0.001"'
HARD, FIRM, LIGHT = np.inf, 12.0, 6.0  # N the scoop may press down (wrist force beyond its own weight)
FAST, PROBE, SLOW = 0.05, 0.003, 0.004  # m per control step: the plunge, the forceful scoop's press, the gentle scoop
# variant -> per particle: damping on translation (N s/m) and on rotation (N m s/rad), dry friction on translation (N)
ICE = {"prior": (1.0, 2e-5, 5.0), "shifted": (0.001, 1e-7, 0.0), "control": (1.0, 2e-5, 0.0)}
# MuJoCo's default friction constraint is so soft for a 4 g ball that it yields like a light damper and never
# reaches its limit; a stiff, nearly hard one holds the ball until the push on it exceeds the friction.
PASTE = 'solreffriction="0.004 1" solimpfriction="0.99 0.999 0.001"'
# The press aims the bowl floor 2.5 mm into the bottom layer: melted ice cream lets the scoop reach it with little
# force, frozen ice cream holds it up near the surface against the firm push.
PRESS_Z = 2 * R - 0.0025
SKIM_Z = 2 * R - 0.0015  # the gentle scoop rides on the bottom layer and gathers the top one
PRESS_HOLD = 12  # control steps the forceful scoop holds its press


def _lattice() -> np.ndarray:
    """Two stable layers: a square layer and a smaller one in its hollows."""
    pts = []
    for i in range(NX):
        for j in range(NY):
            pts.append((R * (2 * i + 1 - NX), R * (2 * j + 1 - NY), R))
    for i in range(NX - 1):
        for j in range(NY - 1):
            pts.append((R * (2 * i + 2 - NX), R * (2 * j + 2 - NY), R + np.sqrt(2) * R))
    return np.array(pts)


LATTICE = _lattice()
SCOOP_IN = -(TUB_IN[0] - BOWL[0] - 4 * BOWL[2])  # where the scoop goes in: its back wall clear of the tub's


class ScoopExpert(Expert):
    """Legs (name, dx of the bowl from the tub centre, bowl-floor height, pitch, m/step, rad/step, push N, hold).

    `push` caps how hard the scoop may press down: once the wrist feels more, the scoop stops sinking. `hold`:
    control steps the leg's goal is held once reached before the next leg.
    """

    def __init__(self, legs: list[tuple[str, float, float, float, float, float, float, int]]) -> None:
        self.legs = legs
        self.leg = 0
        self.wait = 0
        self.target: np.ndarray | None = None
        self._fz, self._free = 0, 0.0

    def resume(self, physics: Physics) -> None:
        """From where the scoop is: already in the ice cream, sink and drag with this skill's speed and push cap
        (its second leg); otherwise start with the hover."""
        self.start_from(physics)
        if robot_in_contact(physics.data, robot_geom_mask(physics.model)):
            self.leg = 1

    def start_from(self, physics: Physics) -> None:
        """Take the hand's pose as the command to move on from. The push is counted from the wrist force with
        nothing touched, the hand's own weight along the sensor's axis at its present pitch: known, not read, so
        that a skill taking over while the scoop presses into the ice cream does not count that press as free."""
        model, data = physics.model, physics.data
        self.target = physics.sensors.arm_position(data)
        sensor = model.sensor("wrist_force")
        self._fz = sensor.adr[0] + 2
        site = sensor.objid[0]
        weight = model.body_subtreemass[model.site_bodyid[site]] * -model.opt.gravity[2]
        self._free = weight * data.site_xmat[site][8]

    def act(self, physics: Physics) -> np.ndarray:
        tub = physics.model.body("tub").pos
        pos = physics.sensors.arm_position(physics.data)
        if self.target is None:
            self.start_from(physics)
        _, dx, dz, pitch, speed, turn, push, hold = self.legs[self.leg]
        # Hand position that puts the bowl floor at the goal for the wrist's present pitch.
        off = np.array([BOWL_Z * np.sin(pos[3]), 0.0, BOWL_Z * np.cos(pos[3])])
        goal = np.array([tub[0] + dx, tub[1], dz + BOWL[2]]) - off
        pressing = self._free - physics.data.sensordata[self._fz]
        if pressing > push:  # felt enough resistance: sink no deeper than the scoop is commanded now
            goal[2] = max(goal[2], self.target[2])
        self.target[:3] += np.clip(goal - self.target[:3], -speed, speed)
        self.target[3] += np.clip(pitch - self.target[3], -turn, turn)
        if np.allclose(self.target[:3], goal, atol=1e-3) and abs(self.target[3] - pitch) < 1e-6:
            # Reached on command; move on once the arm has caught up (or is held back, e.g. pressing down).
            self.wait += 1
            caught_up = np.linalg.norm(pos[:3] - self.target[:3]) < 0.006 or self.wait >= 4
            if caught_up and self.wait >= hold:
                self.leg, self.wait = min(self.leg + 1, len(self.legs) - 1), 0
        return np.array([*self.target, -1.0], dtype=np.float32)


@register_scenario
class IceCream(Scenario):
    info = SCENARIO_INFOS["ice_cream"]
    skills = {
        "forceful_scoop": partial(
            ScoopExpert,
            [
                ("hover", SCOOP_IN, BED_TOP + 0.02, 0.0, 0.015, 0.1, HARD, 0),
                ("press", SCOOP_IN, PRESS_Z, 0.0, PROBE, 0.1, FIRM, PRESS_HOLD),
                ("plunge", SCOOP_IN, -0.015, 0.0, FAST, 0.1, HARD, 0),  # aims below the floor: pushes down ~35 N
                ("sweep", SCOOP_IN + 0.022, -0.015, 0.0, FAST, 0.1, HARD, 0),
                ("twist", SCOOP_IN + 0.016, 0.015, -0.6, 0.025, 0.08, HARD, 0),  # turn the scoop up in the ice cream
                ("lift", SCOOP_IN + 0.016, TUB_H + 0.04, -0.6, 0.02, 0.08, HARD, 0),
                ("hold", SCOOP_IN + 0.016, TUB_H + 0.04, -0.6, 0.02, 0.08, HARD, 0),
            ],
        ),
        "gentle_scoop": partial(
            ScoopExpert,
            [
                ("hover", SCOOP_IN, BED_TOP + 0.02, 0.0, 0.015, 0.05, LIGHT, 0),
                ("dip", SCOOP_IN, SKIM_Z, 0.0, SLOW, 0.05, LIGHT, 0),
                ("drag", SCOOP_IN + 0.02, SKIM_Z, 0.0, SLOW, 0.05, LIGHT, 0),
                ("raise", SCOOP_IN + 0.02, BED_TOP, 0.0, SLOW, 0.04, LIGHT, 0),  # up to the surface before turning
                ("twist", SCOOP_IN + 0.02, BED_TOP, -0.6, SLOW, 0.04, LIGHT, 0),
                ("lift", SCOOP_IN + 0.02, TUB_H + 0.03, -0.6, 0.005, 0.04, LIGHT, 0),
                ("hold", SCOOP_IN + 0.02, TUB_H + 0.03, -0.6, 0.005, 0.04, LIGHT, 0),
            ],
        ),
    }

    def parts(self) -> SceneParts:
        wx, wy = TUB_IN[0] + TUB_WALL, TUB_IN[1] + TUB_WALL
        tub_rgb = " ".join(str(v) for v in TUB_RGB)
        walls = "".join(
            f'\n      <geom name="tub_{n}" type="box" size="{sx} {sy} {TUB_H / 2}" pos="{px} {py} {TUB_H / 2}" '
            f'{WALL} rgba="{tub_rgb} 1"/>'
            for n, sx, sy, px, py in (
                ("front", TUB_WALL / 2, wy, TUB_IN[0] + TUB_WALL / 2, 0),
                ("back", TUB_WALL / 2, wy, -TUB_IN[0] - TUB_WALL / 2, 0),
                ("left", wx, TUB_WALL / 2, 0, TUB_IN[1] + TUB_WALL / 2),
                ("right", wx, TUB_WALL / 2, 0, -TUB_IN[1] - TUB_WALL / 2),
            )
        )
        cream = " ".join(str(v) for v in CREAM_RGB["prior"])
        particles = "".join(
            f"""
    <body name="ice_{k}" pos="{p[0]} {p[1]} {p[2]}">
      <joint name="ice_{k}" type="free" {PASTE}/>
      <geom name="ice_{k}" type="sphere" size="{R}" mass="{PARTICLE_MASS}" condim="1" {STIFF}
            rgba="{cream} 1"/>
    </body>"""
            for k, p in enumerate(LATTICE)
        )
        bx, by, bz = BOWL
        metal = f'rgba="0.75 0.75 0.78 1" priority="1" friction="0.3 0.005 0.0001" {STIFF}'
        hand = f"""
        <geom name="scoop_floor" type="box" size="{bx} {by} {bz}" pos="0 0 {BOWL_Z}" mass="0.02" {metal}/>
        <geom name="scoop_back" type="box" size="{bz} {by} {BOWL_WALL / 2}" pos="{-bx} 0 {BOWL_Z + BOWL_WALL / 2}"
              mass="0.01" {metal}/>
        <geom name="scoop_left" type="box" size="{bx} {bz} {BOWL_WALL / 2}" pos="0 {by} {BOWL_Z + BOWL_WALL / 2}"
              mass="0.01" {metal}/>
        <geom name="scoop_right" type="box" size="{bx} {bz} {BOWL_WALL / 2}" pos="0 {-by} {BOWL_Z + BOWL_WALL / 2}"
              mass="0.01" {metal}/>
        <geom name="scoop_handle" type="box" size="0.003 0.006 {(-BOWL_Z - BOWL_WALL) / 2}"
              pos="{-bx} 0 {(BOWL_Z + BOWL_WALL) / 2}" rgba="0.3 0.3 0.32 1" mass="0.01"/>"""
        return SceneParts(
            # Newton converges in two or three iterations on this small bed, where CG leaves a pressed bed unconverged.
            option='solver="Newton" iterations="10" ls_iterations="20"',
            hand=hand,
            worldbody=f"""
    <body name="tub" pos="0 0 0">
      <geom name="tub_floor" type="box" size="{wx} {wy} 0.001" pos="0 0 0.001" rgba="{tub_rgb} 1"
            contype="0" conaffinity="0"/>{walls}
    </body>{particles}""",
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        # The shared scene fixes cone="elliptic" in XML; a particle scene runs much faster with pyramidal cones.
        model.opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
        n = len(LATTICE)
        self._gids = np.array([model.geom(f"ice_{k}").id for k in range(n)])
        self._bids = np.array([model.body(f"ice_{k}").id for k in range(n)])
        damping, spin_damping, friction = ICE[variant]
        tub_xy = rng.uniform(-0.012, 0.012, 2)
        model.body_pos[model.body("tub").id] = [tub_xy[0], tub_xy[1], 0.0]
        jitter = rng.uniform(-0.02, 0.02, 3)
        start = LATTICE + [tub_xy[0], tub_xy[1], 0.0003]
        start[:, :2] += rng.uniform(-JIGGLE, JIGGLE, (n, 2))
        for k in range(n):
            jnt = model.body_jntadr[self._bids[k]]
            dof, adr = model.jnt_dofadr[jnt], model.jnt_qposadr[jnt]
            model.dof_damping[dof : dof + 3] = damping
            model.dof_damping[dof + 3 : dof + 6] = spin_damping
            model.dof_frictionloss[dof : dof + 3] = friction
            model.geom_rgba[self._gids[k]] = [*(CREAM_RGB[variant] + jitter), 1.0]
            data.qpos[adr : adr + 3] = start[k]
            data.qpos[adr + 3 : adr + 7] = [1, 0, 0, 0]
        self._tub = np.array(tub_xy)
        self._floor = model.geom("scoop_floor").id
        self._done = 0

    def _scooped(self, d: mujoco.MjData) -> np.ndarray:
        """Which balls of ice cream are held inside the scoop (in the bowl's frame, below its rim)."""
        centre = d.geom_xpos[self._floor]
        local = (d.xpos[self._bids] - centre) @ d.geom_xmat[self._floor].reshape(3, 3)
        inside = (np.abs(local[:, 0]) < BOWL[0] + R) & (np.abs(local[:, 1]) < BOWL[1]) & (local[:, 2] > 0)
        return inside & (local[:, 2] < BOWL_WALL)

    def in_scoop(self, d: mujoco.MjData) -> int:
        return int(self._scooped(d).sum())

    def spilled(self, d: mujoco.MjData) -> int:
        """Balls of ice cream outside the tub's footprint and not in the scoop."""
        xy = d.xpos[self._bids][:, :2] - self._tub
        out = (np.abs(xy[:, 0]) > TUB_IN[0] + TUB_WALL) | (np.abs(xy[:, 1]) > TUB_IN[1] + TUB_WALL)
        return int((out & ~self._scooped(d)).sum())

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        if self.spilled(d) > 0:
            return StepOutcome(catastrophe="spill")
        above = d.geom_xpos[self._floor][2] > TUB_H + 0.01
        self._done = self._done + 1 if above and self.in_scoop(d) >= MIN_SCOOPED else 0
        return StepOutcome(success=self._done >= 3)

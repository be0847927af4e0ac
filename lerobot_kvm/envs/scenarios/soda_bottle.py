"""C17 soda bottle, full vs empty: a quick push slides a full bottle but knocks an empty one over.

A full bottle is heavy with its centre of mass low in the liquid; an empty one weighs a few
grams with its centre of mass near mid-height (neck and cap). The quick push hits the bottle at
speed and stops abruptly: the light empty bottle is kicked ahead of the pusher and slides free,
and the friction at its base (mu * COM height > radius) plus the kick tip it over. A slow push
low on the bottle keeps the contact and never lets it slide free.
"""

from functools import partial
from typing import Any

import mujoco
import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import PushExpert
from ..physics import Physics, set_free_body_pose
from ..scenario import Scenario, StepOutcome, register_scenario
from ..scene import SceneParts, scenario_parts, vector

RADIUS = 0.032
HALF_HEIGHT = 0.075  # bottle body; the neck and cap add 3 cm on top
START_X = 0.04
PUSH_DISTANCE = 0.08  # success: the bottle ends at least this far along +x, upright
TIP_ANGLE = np.deg2rad(40.0)  # tilt of the bottle axis that counts as knocked over
UPRIGHT_ANGLE = np.deg2rad(8.0)
BOTTLE_RGB = np.array([0.35, 0.62, 0.42])  # green PET (the neck, always empty)
# what the body looks like (opaque, cheap to render): dark with soda, pale green when empty
BODY_RGB = {
    "prior": np.array([0.24, 0.22, 0.12]),
    "control": np.array([0.20, 0.15, 0.08]),
    "shifted": np.array([0.55, 0.75, 0.60]),
}
SHELL_MASS = 0.03  # the PET bottle itself; its COM sits a little above mid-height (neck and cap)
SHELL_COM = 0.012
LIQUID_COM = -0.025  # centre of the liquid column below the bottle's geometric centre
LIQUID_MASS = {"prior": 0.50, "control": 0.62, "shifted": 0.0}


def _liquid_inertia(mass: float) -> np.ndarray:
    """Principal inertia of the liquid column about its own centre (a solid cylinder)."""
    h = 2 * (HALF_HEIGHT + LIQUID_COM)
    ixx = mass * (3 * RADIUS**2 + h**2) / 12
    return np.array([ixx, ixx, mass * RADIUS**2 / 2])


def pusher_front(pitch: float) -> tuple[float, float]:
    """(ahead, height) of the pusher's leading point relative to the hand origin at wrist `pitch`.

    With the fingers closed the pusher is the two fingers (half-width 12 mm along x, 70 mm long) and
    the palm (half-width 20 mm, 24 mm tall). Pitching forward (negative) brings the fingertips ahead.
    """
    c, s = np.cos(pitch), np.sin(pitch)
    tip = (0.012 * c - 0.07 * s, -0.012 * s - 0.07 * c)  # front-bottom corner of the fingers
    palm = (0.02 * c + 0.012 * s, -0.02 * s + 0.012 * c)  # middle of the palm's front face
    return tip if tip[0] > palm[0] else palm


def pusher(push_z: float, pitch: float) -> dict[str, float]:
    """`PushExpert` options that meet the bottle at height `push_z` with the wrist at `pitch`."""
    ahead, height = pusher_front(pitch)
    return {"ahead": ahead, "hand_z": push_z - height, "pitch": pitch}


@register_scenario
class SodaBottle(Scenario):
    info = SCENARIO_INFOS["soda_bottle"]
    skills = {
        "fast_push": partial(PushExpert, speed=0.028, **pusher(push_z=0.095, pitch=0.0)),
        "slow_push": partial(PushExpert, speed=0.004, **pusher(push_z=0.03, pitch=-0.45)),
    }

    def parts(self) -> SceneParts:
        h = 2 * HALF_HEIGHT
        shell = SHELL_MASS * np.array([RADIUS**2 / 2 + h**2 / 12, 0.0, RADIUS**2])
        return scenario_parts(
            "soda_bottle",
            start_x=START_X,
            hh=HALF_HEIGHT,
            r=RADIUS,
            rgb=vector(BOTTLE_RGB, ".3f"),
            shell_com=SHELL_COM,
            shell_mass=SHELL_MASS,
            shell_inertia=vector(shell[[0, 0, 2]], ".3e"),
            neck_z=HALF_HEIGHT + 0.0125,
            cap_z=HALF_HEIGHT + 0.028,
            label_r=RADIUS + 0.0008,
            liquid_com=LIQUID_COM,
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        self._bid = model.body("bottle").id
        # Only masses and inertias change: moving body_ipos would misplace the body's collision bounds.
        liquid = model.body("liquid").id
        model.body_mass[liquid] = LIQUID_MASS[variant]
        model.body_inertia[liquid] = _liquid_inertia(LIQUID_MASS[variant])
        mujoco.mj_setConst(model, data)  # subtree masses and constraint weights follow the new mass
        jitter = rng.uniform(-0.015, 0.015, 3)
        model.geom_rgba[model.geom("bottle").id] = [*(BODY_RGB[variant] + jitter), 1.0]
        model.geom_rgba[model.geom("bottle_neck").id] = [*(BOTTLE_RGB + jitter), 1.0]
        xy = np.array([START_X, 0.0]) + rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "bottle", [xy[0], xy[1], HALF_HEIGHT], yaw=rng.uniform(-np.pi, np.pi))
        self.start = xy.copy()
        self._rest = 0

    def tilt(self, data: mujoco.MjData) -> float:
        return float(np.arccos(np.clip(data.xmat[self._bid][8], -1.0, 1.0)))

    def evaluate(self, physics: Physics) -> StepOutcome:
        d = physics.data
        tilt = self.tilt(d)
        if tilt > TIP_ANGLE:
            return StepOutcome(catastrophe="tip_over")
        moved = d.xpos[self._bid][0] - self.start[0]
        speed = np.linalg.norm(d.cvel[self._bid][3:])
        ok = moved > PUSH_DISTANCE and tilt < UPRIGHT_ANGLE and speed < 0.01
        self._rest = self._rest + 1 if ok else 0
        return StepOutcome(success=self._rest >= 3)

    def expert_context(self) -> dict[str, Any]:
        return {"body": "bottle", "half_depth": RADIUS, "distance": PUSH_DISTANCE}

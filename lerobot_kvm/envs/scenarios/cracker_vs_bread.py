"""C13 cracker vs soft bread: spreading with firm downward pressure crushes soft bread.

The robot holds a flat spreader (a held tool attached to the hand) and spreads across the top of a
slice lying on the table. The slice's top layer rests on a spring mount (a vertical slide joint):
a hard cracker gives under a millimetre at any force; soft bread gives several millimetres and
its crumb yields (MuJoCo joint-spring plasticity, `springyield`) above about 5 N, staying
flattened, read from `data.plastic`. Spreading with the light pressure of a force-regulated touch
works on both.
"""

from functools import partial
from typing import Any

import numpy as np

from ..catalogue import SCENARIO_INFOS
from ..experts import StrokeExpert
from ..physics import (
    Physics,
    StrokeCoverage,
    contact_normal_force,
    geom_ids,
    permanent_set,
    set_free_body_pose,
    yielding_spring,
)
from ..scenario import Scenario, StepOutcome, register_scenario
from ..scene import SceneParts, scenario_parts, vector

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
HOVER = 0.02  # blade height over the slice before the guarded descent
# How the spreader feels for the slice: still over it while reading the free-air force, down 2 mm per step until
# the wrist feels 0.3 N, then pressing up to 4 mm deeper per step for 5 steps before it strokes.
SPREAD = {"descend_step": 0.002, "contact_force": 0.3, "press_step": 0.004, "press_steps": 5, "settle_steps": 4}
TOP_RGB = {"prior": np.array([0.84, 0.66, 0.36]), "shifted": np.array([0.90, 0.76, 0.52])}
SIDE_RGB = {"prior": np.array([0.78, 0.58, 0.30]), "shifted": np.array([0.74, 0.50, 0.26])}
# variant -> (top-layer stiffness N/m, travel m, yield deflection m): a cracker gives 1 mm and never
# yields within the robot's force; soft bread yields at 800 N/m * 6 mm = 4.8 N
SLICE = {"prior": (3000.0, 0.001, 1.0), "shifted": (800.0, 0.008, 0.006)}
CRUSH = 0.002  # m of permanent flattening that counts as crushed bread


@register_scenario
class CrackerVsBread(Scenario):
    info = SCENARIO_INFOS["cracker_vs_bread"]
    # The position loop presses about kp * depth on a hard cracker (12 mm: ~15 N, firm; 2 mm: ~2 N, gentle) and
    # less on soft bread, which gives way.
    skills = {
        "firm_spread": partial(StrokeExpert, press_depth=0.012, **SPREAD),
        "gentle_spread": partial(StrokeExpert, press_depth=0.002, **SPREAD),
    }

    def parts(self) -> SceneParts:
        hx, hy = HALF
        return scenario_parts(
            "cracker_vs_bread",
            hx=hx,
            hy=hy,
            base_hz=BASE_HALF_Z,
            inner_hx=hx - 0.001,
            inner_hy=hy - 0.001,
            crumb_hz=CRUMB / 2,
            crumb_z=BASE_HALF_Z + CRUMB / 2,
            top_z=BASE_HALF_Z + CRUMB + TOP_HALF_Z,
            top_hz=TOP_HALF_Z,
            face_hx=hx - 0.004,
            face_hy=hy - 0.004,
            stiffness=SLICE["prior"][0],
            yield_=SLICE["shifted"][2],
            side=vector(SIDE_RGB["prior"], ".3f"),
            top=vector(TOP_RGB["prior"], ".3f"),
        )

    def reset(self, physics: Physics, variant: str, rng: np.random.Generator) -> None:
        model, data = physics.model, physics.data
        self._bid = model.body("slice").id
        self._slice = geom_ids(model, "slice_top", "slice_base")
        self._blade = geom_ids(model, "spreader_blade")
        stiffness, travel, elastic_limit = SLICE[variant]
        self._plastic = yielding_spring(model, "slice_top", stiffness, elastic_limit, travel)
        jitter = rng.uniform(-0.015, 0.015, 3)
        for name in ("slice_base", "slice_crumb", "slice_top"):
            model.geom_rgba[model.geom(name).id] = [*(SIDE_RGB[variant] + jitter), 1.0]
        model.geom_rgba[model.geom("slice_face").id] = [*(TOP_RGB[variant] + jitter), 1.0]
        xy = np.array([0.02, 0.0]) + rng.uniform(-0.012, 0.012, 2)
        set_free_body_pose(model, data, "slice", [xy[0], xy[1], BASE_HALF_Z], yaw=rng.uniform(-0.1, 0.1))
        self.coverage = StrokeCoverage(BINS)
        self.flattening = 0.0
        self.force = 0.0

    def evaluate(self, physics: Physics) -> StepOutcome:
        m, d = physics.model, physics.data
        self.flattening = permanent_set(d, self._plastic)
        if self.flattening > CRUSH:
            m.geom_rgba[m.geom("slice_face").id, :3] *= 0.85  # squashed, torn crumb
            return StepOutcome(catastrophe="crush")
        self.force = contact_normal_force(d, m, self._slice, self._blade)
        x = None
        if self.force > CONTACT_N:  # spread along the way since the previous step if touching at both ends
            x = (d.geom("spreader_blade").xpos[0] - d.xpos[self._bid][0] + STROKE / 2) / STROKE * BINS
        return StepOutcome(success=self.coverage.update(x) >= COVER)

    def stroke_line(self, physics: Physics) -> tuple[np.ndarray, float]:
        """Where the spreader hovers before the stroke and the x it strokes to: across the middle of the slice."""
        slice_xy = physics.data.body("slice").xpos[:2]
        hover = np.array([slice_xy[0] - STROKE / 2 - 0.003, slice_xy[1], TOP_Z + BLADE_BELOW_HAND + HOVER])
        return hover, slice_xy[0] + STROKE / 2 + 0.006

    def expert_context(self) -> dict[str, Any]:
        return {"line": self.stroke_line}

"""MJCF assembly: one gripper robot and table shared by every scenario.

A scenario contributes only its objects (and any assets/equalities they need); the robot,
camera, lighting and the software-rendering settings live once in `assets/scene.xml` so that
every scene renders fast on CPU and senses the same channels.
"""

import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, fields
from pathlib import Path
from string import Template

# Workspace geometry (metres). The table top is the z=0 plane.
GRIPPER_HOME = (0.0, 0.0, 0.20)
FINGER_OPEN = 0.05  # half-opening of each finger from the palm centre at q=0
FINGER_TRAVEL = 0.045
MAX_FINGER_FORCE = 40.0  # N per finger at grip command 1.0


@dataclass(frozen=True)
class SceneParts:
    """What a scenario adds to the shared scene."""

    worldbody: str
    hand: str = ""  # geoms/bodies attached to the hand (a held tool), in the hand's frame
    assets: str = ""
    equality: str = ""
    contact: str = ""
    option: str = ""


ASSETS = Path(__file__).parent / "assets"
SCENE_XML = Template((ASSETS / "scene.xml").read_text())


def build_scene_xml(parts: SceneParts, *, width: int, height: int, timestep: float = 0.002) -> str:
    """Return the full MJCF of the shared scene (`assets/scene.xml`) with the scenario's parts spliced in."""
    return SCENE_XML.substitute(
        timestep=timestep,
        option=parts.option,
        offwidth=max(width, 96),
        offheight=max(height, 96),
        assets=parts.assets,
        home=" ".join(str(v) for v in GRIPPER_HOME),
        hand=parts.hand,
        palm_half_width=FINGER_OPEN + 0.012,
        finger_open=FINGER_OPEN,
        finger_travel=FINGER_TRAVEL,
        max_finger_force=MAX_FINGER_FORCE,
        worldbody=parts.worldbody,
        equality=parts.equality,
        contact=parts.contact,
    )


def vector(values: Iterable[float], spec: str = "") -> str:
    """An MJCF vector attribute ("x y z"), each value formatted with `spec`."""
    return " ".join(format(v, spec) for v in values)


def scenario_parts(name: str, **values: object) -> SceneParts:
    """A scenario's parts from `assets/scenarios/<name>.xml`, its placeholders filled from `values`.

    The file's root holds one section per `SceneParts` field it uses (`<worldbody>`, `<hand>`, `<assets>`,
    `<equality>`, `<contact>`), whose children are the MJCF spliced in; an `<option>` section's attributes are added
    to the scene's `<option>`.
    """
    root = ET.fromstring(Template((ASSETS / "scenarios" / f"{name}.xml").read_text()).substitute(values))
    known = {f.name for f in fields(SceneParts)}
    parts = {}
    for section in root:
        if section.tag not in known:
            raise ValueError(f"{name}.xml: unknown section <{section.tag}>; expected one of {sorted(known)}")
        if section.tag == "option":
            parts["option"] = " ".join(f'{k}="{v}"' for k, v in section.attrib.items())
        else:
            parts[section.tag] = "".join(ET.tostring(child, encoding="unicode") for child in section)
    return SceneParts(**parts)

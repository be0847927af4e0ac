"""Physics read-outs shared by scenarios (contact forces, body lookups) and the view of the simulation they get."""

from dataclasses import dataclass

import mujoco
import numpy as np

from .sensing import Sensors

_WRENCH = np.zeros(6)


@dataclass(frozen=True)
class Physics:
    """What a scenario's hooks and its experts see of a running env: the simulation and the robot's sensors.

    Handing hooks this view rather than the env keeps scenarios independent of the gym wrapper (no import of it,
    no access to its episode bookkeeping), as in dm_control's `Task` hooks over `Physics`.
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    sensors: Sensors


def geom_ids(model: mujoco.MjModel, *names: str) -> frozenset[int]:
    return frozenset(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names)


def contact_normal_force(
    data: mujoco.MjData, model: mujoco.MjModel, group_a: frozenset[int], group_b: frozenset[int]
) -> float:
    """Total normal force (N) over active contacts between any geom of `group_a` and any of `group_b`."""
    total = 0.0
    for i in range(data.ncon):
        c = data.contact[i]
        g1, g2 = c.geom1, c.geom2
        if (g1 in group_a and g2 in group_b) or (g2 in group_a and g1 in group_b):
            mujoco.mj_contactForce(model, data, i, _WRENCH)
            total += abs(_WRENCH[0])
    return total


def max_pair_force(
    data: mujoco.MjData, model: mujoco.MjModel, target: frozenset[int], others: tuple[frozenset[int], ...]
) -> float:
    """Largest normal force that any one of `others` (e.g. each finger) exerts on `target`."""
    return max(contact_normal_force(data, model, target, g) for g in others)


def set_free_body_pose(model: mujoco.MjModel, data: mujoco.MjData, body: str, pos, yaw: float = 0.0) -> None:
    """Place a free-jointed body at `pos` with a rotation `yaw` about z."""
    jnt = model.body(body).jntadr[0]
    adr = model.jnt_qposadr[jnt]
    data.qpos[adr : adr + 3] = pos
    data.qpos[adr + 3 : adr + 7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]


GRIPPER_GEOMS = frozenset({"palm", "finger_l", "finger_r"})


def robot_geom_mask(model: mujoco.MjModel) -> np.ndarray:
    """[ngeom] bool: the geoms of the robot (the carriage subtree, a held tool included)."""
    return model.body_rootid[model.geom_bodyid] == model.body_rootid[model.body("carriage").id]


def holds_tool(model: mujoco.MjModel) -> bool:
    """The scenario gives the robot something to hold from the start (a geom on the hand besides the gripper)."""
    return bool({model.geom(int(i)).name for i in np.nonzero(robot_geom_mask(model))[0]} - GRIPPER_GEOMS)


def robot_in_contact(data: mujoco.MjData, robot: np.ndarray) -> bool:
    """The robot touches anything that is not itself (`robot` from `robot_geom_mask`)."""
    c = data.contact[: data.ncon]
    return bool(np.any(robot[c.geom1] != robot[c.geom2]))


def yielding_spring(
    model: mujoco.MjModel, joint: str, stiffness: float, elastic_limit: float, travel: float | None = None
) -> int:
    """Give `joint` an elasto-plastic spring (MuJoCo `springyield`): `stiffness`, deflection beyond which it yields
    for good and, if given, a range of [0, `travel`]. Returns the address of its permanent set in `data.plastic`."""
    jnt = model.joint(joint).id
    model.jnt_stiffness[jnt], model.jnt_springyield[jnt] = stiffness, elastic_limit
    if travel is not None:
        model.jnt_range[jnt] = [0.0, travel]
    return int(model.jnt_plasticadr[jnt])


def permanent_set(data: mujoco.MjData, *plastic: int) -> float:
    """The largest permanent deformation among the yielding springs at these `data.plastic` addresses."""
    return max(abs(float(data.plastic[a])) for a in plastic)


class StrokeCoverage:
    """Which of `bins` equal parts of a stroke a tool has swept while touching: a part counts once the tool, in
    contact at two consecutive steps, moved across it (positions in bins from the stroke's start)."""

    def __init__(self, bins: int) -> None:
        self.bins = bins
        self.covered = np.zeros(bins, dtype=bool)
        self._last: float | None = None  # position at the previous step, if the tool was touching then

    def update(self, position: float | None) -> int:
        """Add this step's position (None: not touching); returns how many parts are covered so far."""
        if position is not None:
            lo, hi = sorted((position, position if self._last is None else self._last))
            self.covered[max(0, int(np.floor(lo))) : max(0, min(self.bins, int(np.floor(hi)) + 1))] = True
        self._last = position
        return int(self.covered.sum())

"""What the robot senses: proprioception and the interaction context.

Only quantities a real gripper could measure are exposed (joint positions, wrist F/T,
fingertip touch, actuator efforts, commanded-vs-achieved motion, its own last action).
Nothing here reads an object's parameters or the scenario's variant.
"""

from collections import deque
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the channel names are read without the simulator (the env config's feature shapes)
    import mujoco

ARM_JOINTS = ("x", "y", "z", "pitch")
ACTUATORS = ("x", "y", "z", "pitch", "grip_l", "grip_r")
ACTION_NAMES = ("x", "y", "z", "pitch", "grip")
STATE_NAMES = ("x", "y", "z", "pitch", "finger_width", "grip_applied")
FRAME_NAMES = (  # one control step's sensed interaction context
    *(f"wrist_force_{a}" for a in "xyz"),
    *(f"wrist_torque_{a}" for a in "xyz"),
    "touch_l",
    "touch_r",
    *(f"effort_{a}" for a in ACTUATORS),
    *(f"tracking_error_{j}" for j in ARM_JOINTS),
    "finger_velocity",
    *(f"last_action_{a}" for a in ACTION_NAMES),
)


def context_names(lags: Sequence[int] = ()) -> tuple[str, ...]:
    """The channels of a context that joins the current frame with the frames `lags` steps before it."""
    return (*FRAME_NAMES, *(f"{name}_lag{lag}" for lag in lags for name in FRAME_NAMES))


def check_lags(lags: Sequence[int]) -> tuple[int, ...]:
    """Context lags as a tuple, refusing any that is not a positive integer (steps back)."""
    if any(not isinstance(lag, int) or isinstance(lag, bool) or lag <= 0 for lag in lags):
        raise ValueError(f"context lags must be positive integers, got {list(lags)}")
    return tuple(lags)


class ContextWindow:
    """The sensed context of each control step: its frame followed by the frames `lags` steps before it (the
    episode's first frame while the episode is younger than a lag). A shift that shows in how the interaction
    evolves, a load that leaves the hand over a few steps, is in no single frame; with no lags the context is the
    frame alone."""

    def __init__(self, lags: Sequence[int] = ()) -> None:
        self.lags = check_lags(lags)
        self.names = context_names(self.lags)
        self._frames: deque[np.ndarray] = deque(maxlen=max(self.lags, default=0) + 1)

    def reset(self) -> None:
        self._frames.clear()

    def push(self, frame: np.ndarray) -> np.ndarray:
        """The context of the step whose frame this is (frames are pushed once per step, in order)."""
        self._frames.append(frame)
        if not self.lags:
            return frame
        last = len(self._frames) - 1
        return np.concatenate([frame, *(self._frames[max(last - lag, 0)] for lag in self.lags)])


class Sensors:
    """Resolves ids once so that per-step reads are plain array indexing."""

    def __init__(self, model: "mujoco.MjModel") -> None:
        jid = [model.joint(j).id for j in (*ARM_JOINTS, "finger_l", "finger_r")]
        self._qpos = np.array([model.jnt_qposadr[j] for j in jid])
        self._qvel = np.array([model.jnt_dofadr[j] for j in jid])
        self._home = np.array(
            [model.body("carriage").pos[0], model.body("carriage").pos[1], model.body("carriage").pos[2]]
        )

        def sensor_slice(name: str) -> slice:
            s = model.sensor(name)
            return slice(int(s.adr[0]), int(s.adr[0]) + int(s.dim[0]))

        self._force = sensor_slice("wrist_force")
        self._torque = sensor_slice("wrist_torque")
        self._touch = [sensor_slice("touch_l"), sensor_slice("touch_r")]
        self._act = np.array([model.actuator(a).id for a in ACTUATORS])

    def arm_position(self, data: "mujoco.MjData") -> np.ndarray:
        """Carriage x, y, z in world coordinates and wrist pitch."""
        q = data.qpos[self._qpos[:4]].copy()
        q[:3] += self._home
        return q

    def finger_width(self, data: "mujoco.MjData") -> float:
        """Closing travel of both fingers (0 = fully open)."""
        return float(data.qpos[self._qpos[4]] + data.qpos[self._qpos[5]])

    def touch(self, data: "mujoco.MjData") -> np.ndarray:
        return np.array([data.sensordata[s][0] for s in self._touch])

    def state(self, data: "mujoco.MjData", grip_applied: float) -> np.ndarray:
        return np.concatenate([self.arm_position(data), [self.finger_width(data), grip_applied]]).astype(np.float32)

    def context(self, data: "mujoco.MjData", arm_target: np.ndarray, last_action: np.ndarray) -> np.ndarray:
        finger_vel = data.qvel[self._qvel[4]] + data.qvel[self._qvel[5]]
        return np.concatenate(
            [
                data.sensordata[self._force],
                data.sensordata[self._torque],
                self.touch(data),
                data.actuator_force[self._act],
                arm_target - self.arm_position(data),
                [finger_vel],
                last_action,
            ]
        ).astype(np.float32)

"""What the robot senses: proprioception and the interaction context.

Only quantities a real gripper could measure are exposed (joint positions, wrist F/T,
fingertip touch, actuator efforts, commanded-vs-achieved motion, its own last action).
Nothing here reads an object's parameters or the scenario's variant.
"""

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


def context_names() -> tuple[str, ...]:
    """The channels of the sensed context: one control step's frame."""
    return FRAME_NAMES


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

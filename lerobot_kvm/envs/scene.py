"""MJCF assembly: one gripper robot and table shared by every scenario.

A scenario contributes only its objects (and any assets/equalities they need); the robot,
camera, lighting and the software-rendering settings live here once so that every scene
renders fast on CPU and senses the same channels.
"""

from dataclasses import dataclass

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


_ROBOT = f"""
    <body name="carriage" pos="{GRIPPER_HOME[0]} {GRIPPER_HOME[1]} {GRIPPER_HOME[2]}" gravcomp="1">
      <joint name="x" type="slide" axis="1 0 0" range="-0.25 0.25" damping="60" armature="0.1"/>
      <joint name="y" type="slide" axis="0 1 0" range="-0.25 0.25" damping="60" armature="0.1"/>
      <joint name="z" type="slide" axis="0 0 1" range="-0.19 0.25" damping="60" armature="0.1"/>
      <inertial pos="0 0 0" mass="0.5" diaginertia="0.002 0.002 0.002"/>
      <body name="hand" gravcomp="1">
        <joint name="pitch" type="hinge" axis="0 1 0" range="-1.7 1.7" damping="3" armature="0.01"/>
        <site name="wrist_ft" pos="0 0 0" size="0.005"/>
        {{hand}}
        <geom name="palm" type="box" size="0.02 {FINGER_OPEN + 0.012} 0.012" pos="0 0 0.012"
              rgba="0.25 0.27 0.32 1" mass="0.3"/>
        <body name="finger_l" pos="0 {FINGER_OPEN} -0.035" gravcomp="1">
          <joint name="finger_l" type="slide" axis="0 -1 0" range="0 {FINGER_TRAVEL}" damping="120"/>
          <geom name="finger_l" type="box" size="0.012 0.006 0.035" rgba="0.35 0.37 0.42 1" mass="0.03"
                friction="1.2 0.01 0.001"/>
          <site name="touch_l" type="box" size="0.013 0.008 0.036" pos="0 -0.002 0" rgba="0 0 0 0"/>
        </body>
        <body name="finger_r" pos="0 -{FINGER_OPEN} -0.035" gravcomp="1">
          <joint name="finger_r" type="slide" axis="0 1 0" range="0 {FINGER_TRAVEL}" damping="120"/>
          <geom name="finger_r" type="box" size="0.012 0.006 0.035" rgba="0.35 0.37 0.42 1" mass="0.03"
                friction="1.2 0.01 0.001"/>
          <site name="touch_r" type="box" size="0.013 0.008 0.036" pos="0 0.002 0" rgba="0 0 0 0"/>
        </body>
      </body>
    </body>
"""

_ACTUATORS = f"""
    <position name="x" joint="x" kp="1500" ctrlrange="-0.25 0.25" forcerange="-60 60"/>
    <position name="y" joint="y" kp="1500" ctrlrange="-0.25 0.25" forcerange="-60 60"/>
    <position name="z" joint="z" kp="1500" ctrlrange="-0.19 0.25" forcerange="-80 80"/>
    <position name="pitch" joint="pitch" kp="40" ctrlrange="-1.7 1.7" forcerange="-8 8"/>
    <motor name="grip_l" joint="finger_l" gear="{MAX_FINGER_FORCE}" ctrlrange="-1 1"/>
    <motor name="grip_r" joint="finger_r" gear="{MAX_FINGER_FORCE}" ctrlrange="-1 1"/>
"""

_SENSORS = """
    <force name="wrist_force" site="wrist_ft"/>
    <torque name="wrist_torque" site="wrist_ft"/>
    <touch name="touch_l" site="touch_l"/>
    <touch name="touch_r" site="touch_r"/>
"""


def build_scene_xml(parts: SceneParts, *, width: int, height: int, timestep: float = 0.002) -> str:
    """Return the full MJCF of the shared scene with the scenario's parts spliced in."""
    return f"""
<mujoco model="kvm_obsolescence">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep}" integrator="implicitfast" cone="elliptic" impratio="4" {parts.option}>
    <flag island="enable"/>
  </option>
  <visual>
    <quality shadowsize="0" offsamples="0" numslices="12" numstacks="8" numquads="1"/>
    <global offwidth="{max(width, 96)}" offheight="{max(height, 96)}"/>
    <headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5"/>
  </visual>
  <asset>
    <material name="table" rgba="0.57 0.52 0.47 1"/>  <!-- untextured: a texture costs most of a CPU frame -->
    {parts.assets}
  </asset>
  <worldbody>
    <light name="top" pos="0 -0.2 1.2" dir="0 0.2 -1" directional="true" castshadow="false"/>
    <geom name="table" type="plane" size="0.6 0.6 0.02" material="table" friction="0.8 0.01 0.001"/>
    <camera name="front" pos="0.22 -0.30 0.30" xyaxes="0.806 0.591 0 -0.311 0.424 0.851" fovy="42"/>
    {_ROBOT.replace("{hand}", parts.hand)}
    {parts.worldbody}
  </worldbody>
  <actuator>{_ACTUATORS}</actuator>
  <sensor>{_SENSORS}</sensor>
  <equality>{parts.equality}</equality>
  <contact>{parts.contact}</contact>
</mujoco>
"""

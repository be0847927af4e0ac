"""The `kvm_obsolescence` gymnasium environment: one scenario, one variant at a time."""

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from .catalogue import check_variant
from .physics import Physics
from .scenario import StepOutcome, make_scenario
from .scene import GRIPPER_HOME, build_scene_xml
from .sensing import ACTION_NAMES, STATE_NAMES, Sensors, context_names

ACTION_LOW = np.array([-0.25, -0.25, 0.01, -1.7, -1.0], dtype=np.float32)
ACTION_HIGH = np.array([0.25, 0.25, 0.45, 1.7, 1.0], dtype=np.float32)
GRIP_RATE = 0.12  # max change of the applied grip command per control step (avoids impact spikes)


class KvmObsolescenceEnv(gym.Env):
    """Gripper + scenario objects in MuJoCo.

    Observation: `pixels` {camera: HxWx3 uint8}, `agent_pos` (proprio), `context` (the step's sensed interaction
    context). Action: absolute carriage target x, y, z
    (m), wrist pitch (rad) and a grip command in [-1, 1] (negative opens, positive squeezes with that fraction of
    the maximum finger force), rate-limited inside the env. Reward: 1 on success, -1 on a catastrophe (both end the
    episode), else 0, so `lerobot-eval`'s per-episode reward sums count catastrophes too.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str = "egg_vs_stone",
        variant: str = "prior",
        image_size: int = 96,
        cameras: tuple[str, ...] = ("front",),
        fps: int = 20,
        max_episode_steps: int | None = None,
        render_mode: str = "rgb_array",
        render_size: int = 256,
        instruction: str = "variant",
    ) -> None:
        self.scenario = make_scenario(task)
        check_variant(variant, self.scenario.info)
        self.task = task
        self.variant = variant
        self.instruction = instruction
        self.task_description = self.scenario.info.instruction(variant, instruction)
        self.cameras = tuple(cameras)
        self.image_size = image_size
        self.render_mode = render_mode
        self.render_size = render_size
        self.fps = fps
        self.metadata = {**self.metadata, "render_fps": fps}
        self._max_episode_steps = max_episode_steps or self.scenario.info.max_steps

        xml = build_scene_xml(
            self.scenario.parts(), width=max(image_size, render_size), height=max(image_size, render_size)
        )
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        for cam in self.cameras:
            if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, cam) < 0:
                raise ValueError(f"unknown camera {cam!r}")
        self.n_substeps = max(1, round(1.0 / (fps * self.model.opt.timestep)))
        self.sensors = Sensors(self.model)
        self.physics = Physics(self.model, self.data, self.sensors)  # what the scenario's hooks and experts see
        self._renderer: mujoco.Renderer | None = None
        self._video_renderer: mujoco.Renderer | None = None
        self._home = np.array(GRIPPER_HOME)

        self.action_space = gym.spaces.Box(ACTION_LOW, ACTION_HIGH, dtype=np.float32)
        img = gym.spaces.Box(0, 255, (image_size, image_size, 3), dtype=np.uint8)
        self.observation_space = gym.spaces.Dict(
            {
                "pixels": gym.spaces.Dict({cam: img for cam in self.cameras}),
                "agent_pos": gym.spaces.Box(-np.inf, np.inf, (len(STATE_NAMES),), dtype=np.float32),
                "context": gym.spaces.Box(-np.inf, np.inf, (len(context_names()),), dtype=np.float32),
            }
        )
        self.feature_names = {"action": ACTION_NAMES, "agent_pos": STATE_NAMES, "context": context_names()}
        self.grip_applied = -1.0
        self.arm_target = np.zeros(4)
        self.last_action = np.zeros(len(ACTION_NAMES))
        self.step_count = 0
        self.outcome = StepOutcome()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if options and "variant" in options:
            check_variant(options["variant"], self.scenario.info)
            self.variant = options["variant"]
            self.task_description = self.scenario.info.instruction(self.variant, self.instruction)
        mujoco.mj_resetData(self.model, self.data)
        self.scenario.reset(self.physics, self.variant, self.np_random)
        mujoco.mj_forward(self.model, self.data)
        self.grip_applied = -1.0
        self.arm_target = self.sensors.arm_position(self.data)
        self.last_action = np.concatenate([self.arm_target, [self.grip_applied]])
        self._apply_controls()
        # Let objects settle under the open, still gripper before the first observation.
        for _ in range(self.n_substeps * 4):
            mujoco.mj_step(self.model, self.data)
        self.step_count = 0
        self.outcome = StepOutcome()
        return self._observation(), self._info()

    def step(self, action: np.ndarray):
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (len(ACTION_NAMES),):
            raise ValueError(f"action must have shape ({len(ACTION_NAMES)},), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains non-finite values: {action}")
        action = np.clip(action, ACTION_LOW, ACTION_HIGH)
        self.arm_target = action[:4]
        self.grip_applied = float(np.clip(action[4], self.grip_applied - GRIP_RATE, self.grip_applied + GRIP_RATE))
        self.last_action = action
        self._apply_controls()
        mujoco.mj_step(self.model, self.data, nstep=self.n_substeps)
        self.step_count += 1

        self.outcome = self.scenario.evaluate(self.physics)
        terminated = self.outcome.success or self.outcome.catastrophe is not None
        truncated = not terminated and self.step_count >= self._max_episode_steps
        reward = float(self.outcome.success) - float(self.outcome.catastrophe is not None)  # 1 / -1 / 0
        return self._observation(), reward, terminated, truncated, self._info()

    def render(self) -> np.ndarray:
        if self._video_renderer is None:
            self._video_renderer = mujoco.Renderer(self.model, self.render_size, self.render_size)
        self._video_renderer.update_scene(self.data, camera=self.cameras[0])
        return self._video_renderer.render().copy()

    def close(self) -> None:
        for r in (self._renderer, self._video_renderer):
            if r is not None:
                r.close()
        self._renderer = self._video_renderer = None

    # ------------------------------------------------------------------ helpers
    def _apply_controls(self) -> None:
        d = self.data
        d.ctrl[0:3] = self.arm_target[:3] - self._home
        d.ctrl[3] = self.arm_target[3]
        d.ctrl[4] = d.ctrl[5] = self.grip_applied

    def camera_image(self, camera: str) -> np.ndarray:
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self.image_size, self.image_size)
        self._renderer.update_scene(self.data, camera=camera)
        return self._renderer.render().copy()

    def _observation(self) -> dict[str, Any]:
        return {
            "pixels": {cam: self.camera_image(cam) for cam in self.cameras},
            "agent_pos": self.sensors.state(self.data, self.grip_applied),
            "context": self.sensors.context(self.data, self.arm_target, self.last_action),
        }

    def _info(self) -> dict[str, Any]:
        return {
            "is_success": bool(self.outcome.success),
            "catastrophe": self.outcome.catastrophe is not None,
            "catastrophe_kind": self.outcome.catastrophe or "",
            "scenario": self.task,
            "variant": self.variant,
        }

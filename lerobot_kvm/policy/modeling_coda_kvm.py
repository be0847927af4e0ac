"""`coda_kvm` policy: CODA-Prompt pool (queried by the frozen task-string embedding) prefix-tuning a small
VLA-style backbone that predicts action chunks (L1 on normalized actions, ACT-style).

Skill weights v [B, n_skills] (the KVM's validity scores, eq. 3) can be passed to `forward`,
`predict_action_chunk` and `select_action`; leaving them out (or all ones) is plain CODA-Prompt.
"""

from collections import deque
from collections.abc import Sequence
from typing import Any

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE
from lerobot.utils.device_utils import resolve_safetensors_device
from safetensors.torch import load_file
from torch import Tensor

from .backbone import PromptedBackbone
from .coda_prompt import CodaPromptPool, Skill
from .configuration_coda_kvm import CodaKvmConfig
from .text_encoder import FrozenTextEncoder

TASK_KEY = "task"
ACTION_PAD_KEY = "action_is_pad"
# A fixed sentence whose embedding is stored with the weights: the query function must never change after
# skills are learned, so a checkpoint refuses to run with an encoder that embeds it differently.
_QUERY_PROBE = "pick up the object and place it on the target"
_QUERY_TOLERANCE = 1e-4


class CodaKvmPolicy(PreTrainedPolicy):
    """CODA-Prompt continual-learning policy; the KVM (a later module) weights its skills."""

    config_class = CodaKvmConfig
    name = "coda_kvm"

    def __init__(self, config: CodaKvmConfig, **kwargs: Any) -> None:
        # kwargs: LeRobot passes dataset_stats= and dataset_meta=; normalization lives in the processors.
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.text_encoder = FrozenTextEncoder(config.text_encoder, config.query_dim)
        self.backbone = PromptedBackbone(
            image_shape=config.image_shape,
            n_cameras=len(config.image_features),
            state_dim=config.state_dim,
            context_dim=config.context_dim,
            action_dim=config.action_dim,
            chunk_size=config.chunk_size,
            vision_channels=list(config.vision_channels),
            dim_model=config.dim_model,
            n_layers=config.n_layers,
            n_heads=config.n_heads,
            dim_feedforward=config.dim_feedforward,
            dropout=config.dropout,
        )
        self.pool = CodaPromptPool(
            n_layers=config.prompt_layers,
            pool_size=config.pool_size,
            n_tasks=config.n_tasks,
            prompt_length=config.prompt_length,
            dim_model=config.dim_model,
            query_dim=config.query_dim,
        )
        self.register_buffer("query_fingerprint", torch.zeros(config.query_dim))
        self._query_checked = False
        self.register_load_state_dict_post_hook(CodaKvmPolicy._after_load)
        self.backbone.requires_grad_(config.train_backbone)
        self.pool.begin_skill(config.skill_name, config.skill_description)
        self.reset()

    @staticmethod
    def _after_load(module: "CodaKvmPolicy", _incompatible_keys: object) -> None:
        module._query_checked = False  # a loaded fingerprint must be checked against this process's encoder

    # ----------------------------------------------------------------- skills
    @property
    def skills(self) -> list[Skill]:
        return self.pool.skills

    @property
    def n_skills(self) -> int:
        return self.pool.n_skills

    def begin_new_skill(self, name: str, description: str = "") -> int:
        """Freeze the current skill and start learning a new one; rebuild the optimizer afterwards."""
        index = self.pool.begin_skill(name, description)
        self.reset()
        return index

    # ----------------------------------------------------------------- LeRobot API
    def get_optim_params(self) -> list[dict[str, Any]]:
        """Trainable parameters only; prompt parameters get no weight decay (old skills must never drift)."""
        backbone = [p for p in self.backbone.parameters() if p.requires_grad]
        prompts = [p for p in self.pool.parameters() if p.requires_grad]
        groups: list[dict[str, Any]] = []
        if backbone:
            groups.append({"params": backbone})
        if prompts:
            groups.append({"params": prompts, "weight_decay": 0.0})
        return groups

    def reset(self) -> None:
        self._action_queue: deque[Tensor] = deque([], maxlen=self.config.n_action_steps)

    def forward(
        self, batch: dict[str, Any], reduction: str = "mean", skill_weights: Tensor | None = None
    ) -> tuple[Tensor, dict[str, float]]:
        """L1 between predicted and target normalized action chunks, ignoring padded steps."""
        if reduction not in ("mean", "none"):
            raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")
        pred = self._predict(batch, skill_weights)
        target, valid = self._check_action(batch, pred.shape[0])
        err = (pred - target).abs() * valid.unsqueeze(-1)
        per_sample = err.sum(dim=(1, 2)) / (valid.sum(dim=1) * pred.shape[-1]).clamp_min(1)
        l1 = err.sum() / (valid.sum() * pred.shape[-1]).clamp_min(1)
        info = {"l1_loss": l1.item()}
        loss = per_sample if reduction == "none" else l1
        if self.config.ortho_weight > 0:
            ortho = self.pool.ortho_penalty()
            loss = loss + self.config.ortho_weight * ortho
            info["ortho_loss"] = ortho.item()
        return loss, info

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Any], skill_weights: Tensor | None = None) -> Tensor:
        """Normalized action chunk [B, chunk_size, action_dim]."""
        self.eval()
        return self._predict(batch, skill_weights)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Any], skill_weights: Tensor | None = None) -> Tensor:
        """Next normalized action [B, action_dim]; a new chunk (with the given skill weights) every
        `n_action_steps` calls."""
        self.eval()
        if not self._action_queue:
            chunk = self._predict(batch, skill_weights)[:, : self.config.n_action_steps]
            self._action_queue.extend(chunk.transpose(0, 1))
        return self._action_queue.popleft()

    # ----------------------------------------------------------------- query and prompt
    def encode_query(self, tasks: Sequence[str]) -> Tensor:
        """Frozen CODA query q(x) [B, query_dim] of the task strings, on the policy's device."""
        device = self.query_fingerprint.device
        if not self._query_checked:
            self._check_query_function(device)
        return self.text_encoder.encode(tasks, device)

    def _check_query_function(self, device: torch.device) -> None:
        probe = self.text_encoder.encode([_QUERY_PROBE], device)[0]
        with torch.inference_mode(False), torch.no_grad():
            if not self.query_fingerprint.any():
                self.query_fingerprint.copy_(probe)
            elif (probe - self.query_fingerprint).abs().max() > _QUERY_TOLERANCE:
                raise ValueError(
                    f"text_encoder {self.config.text_encoder!r} embeds differently from the encoder these "
                    "skills were learned with; the CODA keys would silently change meaning"
                )
        self._query_checked = True

    def skill_relevance(self, tasks: Sequence[str]) -> Tensor:
        """Per-skill relevance alpha_i [B, n_skills] of the task strings."""
        return self.pool.skill_relevance(self.encode_query(tasks))

    def skill_prompts(self, tasks: Sequence[str]) -> Tensor:
        """Per-skill prompt contributions c_i [prompt_layers, B, n_skills, prompt_length, dim_model]."""
        return self.pool.skill_prompts(self.encode_query(tasks))

    def _predict(self, batch: dict[str, Any], skill_weights: Tensor | None) -> Tensor:
        batch_size = self._check_observation(batch)
        query = self.encode_query(self._tasks(batch, batch_size))
        prompts = self.pool(query, skill_weights)
        images = [batch[key] for key in self.config.image_features]
        return self.backbone(images, batch[OBS_STATE], batch[self.config.context_key], prompts)

    # ----------------------------------------------------------------- input checks
    def _check_observation(self, batch: dict[str, Any]) -> int:
        """Every observation key present, shaped [B, *feature_shape] with one B, finite; returns B."""
        batch_size: int | None = None
        for key in (*self.config.image_features, OBS_STATE, self.config.context_key):
            if key not in batch:
                raise ValueError(f"missing observation key '{key}'; batch has keys {sorted(batch)}")
            value = batch[key]
            if not isinstance(value, Tensor):
                raise ValueError(f"observation '{key}' must be a torch.Tensor, got {type(value).__name__}")
            feature_shape = tuple(self.config.input_features[key].shape)
            size = batch_size if batch_size is not None else "B"
            if (
                value.ndim != len(feature_shape) + 1
                or tuple(value.shape[1:]) != feature_shape
                or (batch_size is not None and value.shape[0] != batch_size)
            ):
                raise ValueError(
                    f"observation '{key}' must have shape [{size}, {', '.join(map(str, feature_shape))}], "
                    f"got {list(value.shape)}"
                )
            batch_size = value.shape[0]
            if not torch.isfinite(value).all():
                raise ValueError(f"observation '{key}' contains NaN or inf values")
        return batch_size

    def _tasks(self, batch: dict[str, Any], batch_size: int) -> list[str]:
        tasks = batch.get(TASK_KEY)
        if isinstance(tasks, str):
            return [tasks] * batch_size
        if not isinstance(tasks, list | tuple) or not all(isinstance(t, str) for t in tasks):
            raise ValueError(f"'{TASK_KEY}' must be a string or a list of {batch_size} strings, got {tasks!r}")
        if len(tasks) != batch_size:
            raise ValueError(f"'{TASK_KEY}' has {len(tasks)} strings for a batch of {batch_size}")
        return list(tasks)

    def _check_action(self, batch: dict[str, Any], batch_size: int) -> tuple[Tensor, Tensor]:
        """Target chunk [B, chunk, A] and validity mask [B, chunk] (from `action_is_pad`, if present)."""
        expected = [batch_size, self.config.chunk_size, self.config.action_dim]
        target = batch.get(ACTION)
        if not isinstance(target, Tensor) or list(target.shape) != expected:
            got = list(target.shape) if isinstance(target, Tensor) else type(target).__name__
            raise ValueError(f"'{ACTION}' must have shape {expected}, got {got}")
        if not torch.isfinite(target).all():
            raise ValueError(f"'{ACTION}' contains NaN or inf values")
        pad = batch.get(ACTION_PAD_KEY)
        if pad is None:
            return target, torch.ones(expected[:2], dtype=target.dtype, device=target.device)
        if not isinstance(pad, Tensor) or list(pad.shape) != expected[:2]:
            got = list(pad.shape) if isinstance(pad, Tensor) else type(pad).__name__
            raise ValueError(f"'{ACTION_PAD_KEY}' must have shape {expected[:2]}, got {got}")
        return target, (~pad.bool()).to(target.dtype)

    # ----------------------------------------------------------------- loading
    @classmethod
    def _load_as_safetensor(
        cls, model: "CodaKvmPolicy", model_file: str, map_location: str, strict: bool
    ) -> "CodaKvmPolicy":
        """Always strict: a checkpoint with missing, unexpected or mis-shaped tensors is an error, not a
        silently half-initialised policy."""
        state = load_file(model_file, device=resolve_safetensors_device(map_location))
        expected = model.state_dict()
        missing = sorted(set(expected) - set(state))
        unexpected = sorted(set(state) - set(expected))
        mismatched = [
            f"{k}: checkpoint {list(state[k].shape)} vs policy {list(v.shape)}"
            for k, v in expected.items()
            if k in state and state[k].shape != v.shape
        ]
        if missing or unexpected or mismatched:
            raise ValueError(
                f"incompatible coda_kvm checkpoint {model_file}: missing keys {missing}, "
                f"unexpected keys {unexpected}, shape mismatches {mismatched}"
            )
        model.load_state_dict(state, strict=True)
        return model

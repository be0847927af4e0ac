"""Tiny `coda_kvm` configs, policies and batches shared by the policy tests (CPU, seconds)."""

from collections.abc import Callable
from typing import Any

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy

IMAGE_KEY = "observation.images.front"
TASKS = ["pick up the stone", "gently pick up the egg", "open the drawer"]


def tiny_features() -> tuple[dict[str, PolicyFeature], dict[str, PolicyFeature]]:
    inputs = {
        IMAGE_KEY: PolicyFeature(FeatureType.VISUAL, (3, 32, 32)),
        "observation.state": PolicyFeature(FeatureType.STATE, (6,)),
        "observation.context": PolicyFeature(FeatureType.STATE, (23,)),
    }
    return inputs, {"action": PolicyFeature(FeatureType.ACTION, (5,))}


def tiny_config(**overrides: Any) -> CodaKvmConfig:
    inputs, outputs = tiny_features()
    kwargs: dict[str, Any] = dict(
        device="cpu",
        input_features=inputs,
        output_features=outputs,
        vision_channels=[8, 8, 8],
        dim_model=32,
        n_layers=2,
        n_heads=2,
        dim_feedforward=64,
        prompt_length=4,
        prompt_layers=2,
        pool_size=6,
        n_tasks=3,
        chunk_size=4,
        n_action_steps=2,
    )
    kwargs.update(overrides)
    return CodaKvmConfig(**kwargs)


def tiny_batch(config: CodaKvmConfig, batch_size: int = 3, with_action: bool = True) -> dict[str, Any]:
    gen = torch.Generator().manual_seed(1)
    batch: dict[str, Any] = {
        key: torch.rand(batch_size, *ft.shape, generator=gen) for key, ft in config.input_features.items()
    }
    batch["task"] = [TASKS[i % len(TASKS)] for i in range(batch_size)]
    if with_action:
        batch["action"] = torch.randn(batch_size, config.chunk_size, config.action_dim, generator=gen)
        pad = torch.zeros(batch_size, config.chunk_size, dtype=torch.bool)
        pad[0, -1] = True
        batch["action_is_pad"] = pad
    return batch


@pytest.fixture
def make_config() -> Callable[..., CodaKvmConfig]:
    return tiny_config


@pytest.fixture
def make_batch() -> Callable[..., dict[str, Any]]:
    return tiny_batch


@pytest.fixture
def make_policy() -> Callable[..., CodaKvmPolicy]:
    def make(**overrides: Any) -> CodaKvmPolicy:
        torch.manual_seed(0)
        return CodaKvmPolicy(tiny_config(**overrides))

    return make

"""Tiny `coda_kvm` policies with a KVM, and hand-made traces, shared by the KVM tests (CPU, seconds)."""

from collections.abc import Callable
from typing import Any

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_kvm.kvm.configuration import KvmConfig
from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy
from lerobot_kvm.policy.feedback import make_demonstration

IMAGE_KEY = "observation.images.front"
CONTEXT_KEY = "observation.context"
CONTEXT_DIM = 8
STONE = "pick up the stone"
EGG = "pick up the egg"


def kvm_config(**overrides: Any) -> KvmConfig:
    kwargs: dict[str, Any] = dict(
        encoder_hidden=[16, 16],
        latent_dim=8,
        energy_hidden=[32, 32, 32],
        skill_embed_dim=4,
        feature_dim=16,
        gate_window=64,
        gate_min_count=8,
        safe_offline_capacity=64,
        safe_online_capacity=64,
        fail_offline_capacity=32,
        fail_online_capacity=32,
        label_capacity=64,
        hypothesis_capacity=4,
        replay_size=8,
        feedback_steps=5,
        feedback_batch=16,
        feedback_hard_safe_replay=4,
        trace_capacity=100,
    )
    kwargs.update(overrides)
    return KvmConfig(**kwargs)


def tiny_config(kvm: KvmConfig | None = None, **overrides: Any) -> CodaKvmConfig:
    inputs = {
        IMAGE_KEY: PolicyFeature(FeatureType.VISUAL, (3, 16, 16)),
        "observation.state": PolicyFeature(FeatureType.STATE, (4,)),
        CONTEXT_KEY: PolicyFeature(FeatureType.STATE, (CONTEXT_DIM,)),
    }
    kwargs: dict[str, Any] = dict(
        device="cpu",
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (3,))},
        vision_channels=[4, 4],
        dim_model=16,
        n_layers=2,
        n_heads=2,
        dim_feedforward=32,
        prompt_length=4,
        prompt_layers=1,
        pool_size=8,
        n_tasks=4,
        chunk_size=4,
        n_action_steps=2,
        skill_name="firm_grasp",
        kvm=kvm or kvm_config(),
    )
    kwargs.update(overrides)
    return CodaKvmConfig(**kwargs)


def tiny_batch(
    config: CodaKvmConfig, batch_size: int = 4, task: str | list[str] = STONE, seed: int = 1, with_action: bool = True
) -> dict[str, Any]:
    gen = torch.Generator().manual_seed(seed)
    batch: dict[str, Any] = {
        key: torch.rand(batch_size, *ft.shape, generator=gen) for key, ft in config.input_features.items()
    }
    batch["task"] = [task] * batch_size if isinstance(task, str) else list(task)
    if with_action:
        batch["action"] = torch.randn(batch_size, config.chunk_size, config.action_dim, generator=gen)
    return batch


def make_policy_fn(**overrides: Any) -> CodaKvmPolicy:
    torch.manual_seed(0)
    return CodaKvmPolicy(tiny_config(**overrides))


def on_device(batch: dict[str, Any], device: torch.device | str) -> dict[str, Any]:
    """What LeRobot's preprocessor does last: the batch's tensors on the policy's device."""
    return {k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}


def run_attempt(policy: CodaKvmPolicy, task: str, steps: int = 6, seed: int = 0, shift: float = 0.0):
    """Drive select_action on random observations (context offset by `shift`); returns the trace."""
    policy.reset()
    for t in range(steps):
        batch = tiny_batch(policy.config, batch_size=1, task=task, seed=seed * 100 + t, with_action=False)
        batch[CONTEXT_KEY] = batch[CONTEXT_KEY] + shift
        policy.select_action(on_device(batch, policy.config.device))
    return policy.kvm_trace()


def demonstration(config: CodaKvmConfig, steps: int = 5) -> dict[str, Any]:
    """A corrective demonstration of random steps that names no skill: a failure with it makes a knowledge gap."""
    per_step = []
    for t in range(steps):
        b = on_device(tiny_batch(config, batch_size=1, task=EGG, seed=50 + t), config.device)
        b["action"] = b["action"][:, 0]
        per_step.append(b)
    return make_demonstration(per_step)


def busy_policy(device: str = "cpu") -> CodaKvmPolicy:
    """A policy whose KVM has used every kind of memory: offline training with dataset labels, a failure with a
    demonstration (a new skill), a success with interventions, another success, a pruned skill."""
    policy = make_policy_fn(kvm=kvm_config(gate_k=2.5, gate_min_count=4), device=device).to(device)
    policy.kvm_set_episode_labels(
        [
            {"episode_index": 0, "skill": "firm_grasp", "outcome": "success", "variant": "prior"},
            {"episode_index": 1, "skill": "firm_grasp", "outcome": "failure", "variant": "prior"},
        ]
    )
    policy.train()
    optimizer = torch.optim.AdamW(policy.get_optim_params(), lr=1e-3)
    for i in range(3):
        batch = tiny_batch(policy.config, task=STONE, seed=i)
        batch["episode_index"] = torch.tensor([0, 0, 0, 1])
        loss, _ = policy.forward(on_device(batch, device))
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
    policy.eval()
    policy.begin_new_skill("gentle_grasp")
    report = policy.kvm_feedback("catastrophe", run_attempt(policy, EGG, steps=4), demonstration(policy.config), 3)
    trace = run_attempt(policy, EGG, steps=4)
    for tele in trace.telemetry:
        tele.validity[:, report["culprit"]] = 0.0
    policy.kvm_feedback("success", trace)
    policy.kvm_feedback("success", run_attempt(policy, STONE, steps=4, seed=3))
    policy.kvm_prune_skill(1)
    return policy


@pytest.fixture
def make_policy() -> Callable[..., CodaKvmPolicy]:
    return make_policy_fn


@pytest.fixture
def to_device() -> Callable[..., dict[str, Any]]:
    return on_device


@pytest.fixture
def make_busy_policy() -> Callable[..., CodaKvmPolicy]:
    return busy_policy


@pytest.fixture
def make_batch() -> Callable[..., dict[str, Any]]:
    return tiny_batch


@pytest.fixture
def make_kvm_config() -> Callable[..., KvmConfig]:
    return kvm_config


@pytest.fixture
def make_config() -> Callable[..., CodaKvmConfig]:
    return tiny_config


@pytest.fixture
def attempt() -> Callable[..., Any]:
    return run_attempt

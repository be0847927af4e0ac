"""Config validation, LeRobot registration, and the pre/post-processing pipeline (the task string survives)."""

import dataclasses
import json

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.optim import AdamWConfig
from lerobot.policies.factory import get_policy_class, make_pre_post_processors

from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy, make_coda_kvm_pre_post_processors


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"pool_size": 7, "n_tasks": 3}, "pool_size"),
        ({"prompt_length": 3}, "prompt_length"),
        ({"n_action_steps": 5, "chunk_size": 4}, "n_action_steps"),
        ({"prompt_layers": 3, "n_layers": 2}, "prompt_layers"),
        ({"dim_model": 0}, "dim_model"),
        ({"dim_model": 30, "n_heads": 4}, "dim_model"),
        ({"n_tasks": -1}, "n_tasks"),
        ({"dropout": 1.0}, "dropout"),
        ({"pool_size": 600, "n_tasks": 3}, "pool_size"),
        ({"vision_channels": []}, "vision_channels"),
        ({"skill_name": " "}, "skill_name"),
        ({"ortho_weight": -1.0}, "ortho_weight"),
    ],
)
def test_bad_config_values_raise_value_error_naming_the_field(make_config, overrides, field) -> None:
    with pytest.raises(ValueError, match=field):
        make_config(**overrides)


@pytest.mark.parametrize("drop", ["observation.images.front", "observation.state"])
def test_missing_features_are_named(make_config, drop) -> None:
    config = make_config()
    config.input_features = {k: v for k, v in config.input_features.items() if k != drop}
    with pytest.raises(ValueError, match=drop.split(".")[1]):
        config.validate_features()


def test_bad_image_shapes_and_missing_action_are_named(make_config) -> None:
    config = make_config()
    config.input_features["observation.images.wrist"] = PolicyFeature(FeatureType.VISUAL, (16, 16))
    with pytest.raises(ValueError, match="observation.images.wrist"):
        config.validate_features()
    config = make_config()
    config.output_features = {}
    with pytest.raises(ValueError, match="action"):
        config.validate_features()


def test_presets_and_registration(make_config) -> None:
    config = make_config(optimizer_lr=3e-4)
    optimizer = config.get_optimizer_preset()
    assert isinstance(optimizer, AdamWConfig) and optimizer.lr == 3e-4
    assert config.get_scheduler_preset() is None
    assert config.action_delta_indices == list(range(config.chunk_size))
    assert config.observation_delta_indices is None and config.reward_delta_indices is None
    assert config.type == "coda_kvm"
    assert PreTrainedConfig.get_choice_class("coda_kvm") is CodaKvmConfig
    assert get_policy_class("coda_kvm") is CodaKvmPolicy
    defaults = CodaKvmConfig()
    assert defaults.normalization_mapping["VISUAL"].value == "IDENTITY"
    assert dataclasses.asdict(defaults)["context_key"] == "observation.context"


def stats_for(config: CodaKvmConfig) -> dict[str, dict[str, torch.Tensor]]:
    stats = {}
    for key in ("observation.state", "observation.context", "action"):
        dim = (config.input_features | config.output_features)[key].shape[0]
        stats[key] = {"mean": torch.linspace(-1, 1, dim), "std": torch.linspace(0.5, 2, dim)}
    return stats


def test_preprocessor_keeps_task_and_normalizes_context(make_config, make_batch, make_policy, tmp_path) -> None:
    config = make_config()
    stats = stats_for(config)
    pre, post = make_coda_kvm_pre_post_processors(config, dataset_stats=stats)
    raw = make_batch(config)
    out = pre(dict(raw))
    assert out["task"] == raw["task"]
    assert torch.equal(out["observation.images.front"], raw["observation.images.front"])
    ctx = stats["observation.context"]
    expected = (raw["observation.context"] - ctx["mean"]) / (ctx["std"] + 1e-8)
    torch.testing.assert_close(out["observation.context"], expected)
    assert torch.equal(out["action_is_pad"], raw["action_is_pad"])
    policy = make_policy()
    loss, _ = policy.forward(out)
    assert torch.isfinite(loss)

    # The checkpoint layout: pipelines saved beside the weights load back through LeRobot's factory.
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    pre2, post2 = make_pre_post_processors(config, pretrained_path=str(tmp_path))
    assert pre2(dict(raw))["task"] == raw["task"]

    # Eval-style unbatched observation with a single task string -> one action, unnormalized on the CPU.
    obs = {k: v[0] for k, v in raw.items() if k.startswith("observation.")}
    obs["task"] = "gently pick up the egg"
    batched = pre2(obs)
    assert batched["task"] == ["gently pick up the egg"]
    action = policy.select_action(batched)
    act = stats["action"]
    torch.testing.assert_close(post2(action), action * act["std"] + act["mean"])


def test_processors_of_a_checkpoint_follow_the_policy_to_its_device(make_config, make_batch, make_policy, tmp_path):
    """A checkpoint trained on another device (its saved preprocessor names `cuda`) runs where the policy now is."""
    from lerobot_kvm.evaluation.rollouts import policy_processors

    config = make_config()
    pre, post = make_coda_kvm_pre_post_processors(config, dataset_stats=stats_for(config))
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    saved = tmp_path / "policy_preprocessor.json"
    pipeline = json.loads(saved.read_text())
    (device_step,) = [s for s in pipeline["steps"] if s.get("registry_name") == "device_processor"]
    assert device_step["config"]["device"] == "cpu"
    device_step["config"]["device"] = "cuda"
    saved.write_text(json.dumps(pipeline))
    policy = make_policy()
    pre2, _ = policy_processors(policy, tmp_path)
    out = pre2(dict(make_batch(config)))
    assert out["observation.context"].device == policy.query_fingerprint.device
    assert torch.isfinite(policy.forward(out)[0])

"""Features of datasets that are not ours: no sensed context, cameras of other and unequal sizes."""

import logging

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_kvm.policy import CodaKvmPolicy
from lerobot_kvm.policy.configuration_coda_kvm import MAX_IMAGE_SIDE


def test_without_a_context_feature_the_kvm_reads_the_state_and_says_so_once(make_config, make_batch, caplog):
    config = make_config()
    del config.input_features["observation.context"]
    config.input_features["observation.state"] = PolicyFeature(FeatureType.STATE, (7,))  # a dim no other test uses
    with caplog.at_level(logging.WARNING):
        config.validate_features()
        policy = CodaKvmPolicy(config)
    assert config.context_key == "observation.state" and config.context_dim == 7
    assert sum("no 'observation.context' input feature" in r.getMessage() for r in caplog.records) == 1
    batch = make_batch(config, batch_size=2)
    loss, _ = policy.forward(batch)
    assert torch.isfinite(loss)
    del batch["action"], batch["action_is_pad"]
    assert torch.isfinite(policy.select_action(batch)).all()


def test_a_named_context_key_is_never_replaced(make_config):
    config = make_config(context_key="observation.forces")
    with pytest.raises(ValueError, match="needs the input feature 'observation.forces'"):
        config.validate_features()


def test_cameras_of_any_size_are_resized_to_the_backbone_input(make_config, make_batch):
    config = make_config()
    config.input_features["observation.images.front"] = PolicyFeature(FeatureType.VISUAL, (3, 240, 320))
    config.input_features["observation.images.wrist"] = PolicyFeature(FeatureType.VISUAL, (3, 20, 24))
    config.validate_features()
    assert config.image_shape == (3, 72, MAX_IMAGE_SIDE)  # aspect kept, no side above the limit
    policy = CodaKvmPolicy(config)
    batch = make_batch(config, batch_size=2, with_action=False)
    assert policy.select_action(batch).shape == (2, config.action_dim)
    small = make_config()
    assert small.image_shape == (3, 32, 32)  # small images keep their size

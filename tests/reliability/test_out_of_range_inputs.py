"""A non-finite or absurd observation is refused by name at every step: never turned into an action."""

import pytest
import torch

from lerobot_kvm.policy import CodaKvmPolicy


@pytest.fixture(scope="module")
def policy(saved_checkpoint) -> CodaKvmPolicy:
    return CodaKvmPolicy.from_pretrained(saved_checkpoint)


def observation(policy: CodaKvmPolicy) -> dict:
    batch = {key: torch.rand(1, *ft.shape) for key, ft in policy.config.input_features.items()}
    return batch | {"task": "pick up the egg"}


@pytest.mark.parametrize("key", ["observation.context", "observation.state", "observation.images.front"])
@pytest.mark.parametrize(
    ("value", "message"), [(1e30, "magnitude 1e\\+30"), (-3e12, "magnitude 3e\\+12"), (float("nan"), "NaN or inf")]
)
def test_an_out_of_range_input_is_named(policy, key, value, message):
    policy.reset()
    assert torch.isfinite(policy.select_action(observation(policy))).all()
    batch = observation(policy)
    batch[key].view(-1)[0] = value
    policy.reset()
    with pytest.raises(ValueError, match=rf"observation '{key}' .*{message}"):
        policy.select_action(batch)


def test_an_unknown_feedback_outcome_is_named(policy):
    outcomes = r"\('success', 'failure', 'abstention', 'catastrophe'\)"
    with pytest.raises(ValueError, match=rf"outcome must be one of {outcomes}, got 'bogus'"):
        policy.kvm_feedback("bogus")

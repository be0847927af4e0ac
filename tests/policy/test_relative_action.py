"""Position targets predicted relative to the state: the mapping from dataset names and statistics, and the policy's
chunk as the network's offset plus the state's value."""

from types import SimpleNamespace

import torch
from lerobot.configs.types import NormalizationMode

from lerobot_kvm.policy import CodaKvmPolicy
from lerobot_kvm.policy.relative_action import state_base, state_offset

ACTION_NAMES = ["x", "y", "z", "pitch", "grip"]
STATE_NAMES = ["x", "y", "z", "pitch", "finger_width", "grip_applied"]
MEAN_STD = NormalizationMode.MEAN_STD


def _stats(mean: list[float], std: list[float]) -> dict[str, torch.Tensor]:
    return {"mean": torch.tensor(mean), "std": torch.tensor(std)}


ACTION_STATS = _stats([0.1, 0.0, 0.2, 0.3, 0.5], [0.05, 0.02, 0.04, 0.1, 0.7])
STATE_STATS = _stats([0.09, 0.01, 0.25, 0.3, 0.02, 0.4], [0.06, 0.03, 0.05, 0.2, 0.01, 0.5])


def test_a_state_value_maps_to_the_same_raw_action_value() -> None:
    index, scale, shift = state_base(
        ACTION_NAMES, STATE_NAMES, ACTION_STATS, STATE_STATS, MEAN_STD, MEAN_STD, len(ACTION_NAMES)
    )
    assert index.tolist() == [0, 1, 2, 3, -1]  # the grip command has no state of its name: absolute
    raw_state = torch.tensor([[0.13, -0.02, 0.31, 0.45, 0.015, 0.9]])
    norm_state = (raw_state - STATE_STATS["mean"]) / STATE_STATS["std"]
    base = state_offset(norm_state, index, scale, shift)
    raw_action = base[:, :4] * ACTION_STATS["std"][:4] + ACTION_STATS["mean"][:4]
    torch.testing.assert_close(raw_action, raw_state[:, :4], atol=1e-5, rtol=0)
    assert base[0, 4] == 0


def test_min_max_statistics_map_the_same_way() -> None:
    minmax = NormalizationMode.MIN_MAX
    a_stats = {"min": torch.tensor([-0.1, 0.0]), "max": torch.tensor([0.3, 1.0])}
    s_stats = {"min": torch.tensor([-0.2]), "max": torch.tensor([0.2])}
    index, scale, shift = state_base(["x", "grip"], ["x"], a_stats, s_stats, minmax, minmax, 2)
    raw = 0.05
    norm_state = torch.tensor([[2 * (raw + 0.2) / 0.4 - 1]])
    base = state_offset(norm_state, index, scale, shift)
    assert abs(float((base[0, 0] + 1) / 2 * 0.4 - 0.1) - raw) < 1e-6 and base[0, 1] == 0


def test_a_constant_action_dimension_stays_absolute() -> None:
    constant = _stats([0.1, 0.0, 0.2, 0.0, 0.5], [0.05, 0.02, 0.04, 0.0, 0.7])  # every demonstration's pitch is 0
    index, scale, _ = state_base(ACTION_NAMES, STATE_NAMES, constant, STATE_STATS, MEAN_STD, MEAN_STD, 5)
    assert index.tolist() == [0, 1, 2, -1, -1] and float(scale.abs().max()) < 10


def test_without_names_or_statistics_actions_stay_absolute() -> None:
    for names, stats in ((None, ACTION_STATS), (ACTION_NAMES, None)):
        index, _, _ = state_base(names, STATE_NAMES, stats, STATE_STATS, MEAN_STD, MEAN_STD, 5)
        assert (index == -1).all()


def test_the_policy_chunk_is_the_network_offset_plus_the_state(make_config, make_batch) -> None:
    features = {"action": {"names": ACTION_NAMES}, "observation.state": {"names": STATE_NAMES}}
    stats = {"action": ACTION_STATS, "observation.state": STATE_STATS}
    torch.manual_seed(0)
    policy = CodaKvmPolicy(make_config(), dataset_stats=stats, dataset_meta=SimpleNamespace(features=features))
    torch.manual_seed(0)
    absolute = CodaKvmPolicy(make_config())  # same weights, no dataset: nothing is based on the state
    policy.eval(), absolute.eval()
    assert (absolute.state_base_index == -1).all() and policy.state_base_index.tolist() == [0, 1, 2, 3, -1]
    batch = make_batch(policy.config, batch_size=2, with_action=False)
    weights = torch.ones(2, 1)
    with torch.no_grad():
        alphas = policy.pool.component_alphas(policy.encode_query(batch["task"]))
        chunk = policy.decode(batch, alphas, weights)
        offsets = absolute.decode(batch, alphas, weights)
    state = batch["observation.state"]
    expected = offsets + state_offset(
        state, policy.state_base_index, policy.state_base_scale, policy.state_base_shift
    ).unsqueeze(1)
    torch.testing.assert_close(chunk, expected)
    moved = dict(batch, **{"observation.state": state + torch.tensor([1.0, 0, 0, 0, 0, 0])})
    with torch.no_grad():
        shifted = policy.decode(moved, alphas, weights) - absolute.decode(moved, alphas, weights)
    # one normalized unit of state x moves every planned x target by the same raw distance
    step = float(STATE_STATS["std"][0] / ACTION_STATS["std"][0])
    torch.testing.assert_close(shifted[..., 0] - (chunk - offsets)[..., 0], torch.full((2, 4), step))

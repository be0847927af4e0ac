"""The policy and its KVM on a CUDA device: what runs on the CPU runs there, lands on the device, and a checkpoint
written there loads on the CPU with the same weights and memory (skipped where no CUDA device is present)."""

import copy
from collections.abc import Iterator

import pytest
import torch

from lerobot_kvm.policy import CodaKvmPolicy
from lerobot_kvm.policy.feedback import chunk_targets

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
CUDA = torch.device("cuda")
EGG = "pick up the egg"
STONE = "pick up the stone"


@pytest.fixture(autouse=True)
def _full_precision() -> Iterator[None]:
    """TF32 convolutions would make the CPU comparison a matter of tolerance rather than of placement."""
    matmul = torch.backends.cuda.matmul.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = False
    with torch.backends.cudnn.flags(enabled=True, allow_tf32=False):
        yield
    torch.backends.cuda.matmul.allow_tf32 = matmul


def assert_same(on_gpu: torch.Tensor, on_cpu: torch.Tensor) -> None:
    torch.testing.assert_close(on_gpu.cpu(), on_cpu, atol=1e-5, rtol=1e-4)


def test_a_training_step_on_cuda_keeps_every_tensor_there(make_policy, make_batch, to_device) -> None:
    policy = make_policy(device="cuda").to(CUDA)  # as LeRobot's factory places a policy
    policy.train()
    optimizer = torch.optim.AdamW(policy.get_optim_params(), lr=1e-3)
    before = {k: v.clone() for k, v in policy.state_dict().items()}
    batch = to_device(make_batch(policy.config, task=STONE), CUDA)
    batch["episode_index"] = torch.tensor([0, 0, 1, 1], device=CUDA)
    loss, metrics = policy.forward(batch)
    assert loss.device.type == "cuda" and torch.isfinite(loss)
    assert all(isinstance(v, float) for v in metrics.values()) and "kvm_loss" in metrics
    loss.backward()
    optimizer.step()
    changed = [k for k, v in policy.state_dict().items() if not torch.equal(v, before[k])]
    assert any(k.startswith("kvm.") for k in changed) and any(k.startswith("pool.") for k in changed)
    assert {t.device.type for t in policy.state_dict().values()} == {"cuda"}


def test_acting_on_cuda_matches_the_cpu(make_policy, make_batch, to_device) -> None:
    cpu = make_policy()
    gpu = copy.deepcopy(cpu).to(CUDA)
    gpu.config.device = "cuda"
    cpu.eval()
    gpu.eval()
    batch = make_batch(cpu.config, task=[EGG, STONE, EGG, STONE], with_action=False)
    chunk = gpu.predict_action_chunk(to_device(batch, CUDA))
    assert chunk.device.type == "cuda"
    assert_same(chunk, cpu.predict_action_chunk(batch))
    assert_same(gpu.kvm_validity(to_device(batch, CUDA)), cpu.kvm_validity(batch))
    one = make_batch(cpu.config, batch_size=1, task=EGG, with_action=False)
    assert_same(gpu.select_action(to_device(one, CUDA)), cpu.select_action(one))
    assert_same(gpu.kvm_telemetry.validity, cpu.kvm_telemetry.validity)


def test_feedback_on_cuda_learns_and_its_checkpoint_loads_on_the_cpu(
    make_busy_policy, make_batch, to_device, tmp_path
) -> None:
    """The whole online path (offline training, a failure with a corrective demonstration that makes a new skill,
    interventions, pruning) on the device, then the checkpoint on the CPU: same state, same actions."""
    policy = make_busy_policy("cuda")  # whether the failure makes a skill of its own depends on the random stream
    assert policy.n_skills >= 2 and not policy.kvm_active_skills()[1]
    assert len(policy.kvm.fail_online) and len(policy.kvm.safe_online) and policy.kvm.hypotheses.ids()
    assert {t.device.type for t in policy.state_dict().values()} == {"cuda"}
    policy.save_pretrained(tmp_path)
    config = copy.deepcopy(policy.config)
    config.device = "cpu"
    loaded = CodaKvmPolicy.from_pretrained(tmp_path, config=config)
    original, restored = policy.state_dict(), loaded.state_dict()
    assert original.keys() == restored.keys()
    for key, value in original.items():
        assert restored[key].device.type == "cpu" and torch.equal(value.cpu(), restored[key]), key
    summary, restored_summary = policy.kvm_summary(), loaded.kvm_summary()
    # the gate's statistics are recomputed from its window after a load: the device's reductions round differently
    assert restored_summary.pop("gate") == pytest.approx(summary.pop("gate"), rel=1e-5)
    assert restored_summary == summary
    batch = make_batch(loaded.config, task=EGG, with_action=False)
    assert_same(policy.predict_action_chunk(to_device(batch, CUDA)), loaded.predict_action_chunk(batch))


def test_a_trajectorys_action_chunks_and_padding_stay_on_its_device() -> None:
    target, pad = chunk_targets(torch.randn(5, 3, device=CUDA), 4)
    assert target.device.type == pad.device.type == "cuda" and pad[-1, 1:].all() and not pad[0].any()

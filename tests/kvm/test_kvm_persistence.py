"""Every piece of KVM memory survives save_pretrained / from_pretrained (and `lerobot-train --resume`) exactly."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from lerobot_kvm.policy import CodaKvmPolicy

EGG = "pick up the egg"
MEMORY = (
    "kvm.gate.window.data",
    "kvm.gate.window.count",
    "kvm.gate.stats",
    "kvm.safe_offline.data",
    "kvm.safe_online.flags",
    "kvm.fail_offline.skill",
    "kvm.fail_online.tag",
    "kvm.hypotheses.counter",
    "kvm.hypotheses.prototype",
    "kvm.metabolism.proposed",
    "kvm.metabolism.pruned",
    "kvm.labels.table",
    "kvm.energy.net.0.weight",
    "kvm.classifier.net.0.weight",
    "kvm.encoder.decoder.0.weight",
    "kvm.joint.skill_embed.weight",
    "pool.skill_table",
    "pool.task_count",
)


def test_every_piece_of_kvm_memory_survives_save_and_load(make_busy_policy, make_batch, tmp_path) -> None:
    policy = make_busy_policy()
    kvm = policy.kvm
    assert len(kvm.gate.window) and len(kvm.safe_offline) and len(kvm.fail_offline)
    assert len(kvm.safe_online) and len(kvm.fail_online) and kvm.hypotheses.ids()
    assert int(kvm.hypotheses.counter.max()) == 1 and int(kvm.metabolism.proposed.sum()) > 0
    policy.save_pretrained(tmp_path)
    loaded = CodaKvmPolicy.from_pretrained(tmp_path)
    original, restored = policy.state_dict(), loaded.state_dict()
    assert original.keys() == restored.keys()
    for key in MEMORY:
        assert key in original, key
    for key, value in original.items():
        assert torch.equal(value, restored[key]), key
    assert loaded.config.kvm == policy.config.kvm and loaded.config.kvm.gate_k == 2.5
    assert loaded.kvm_summary() == policy.kvm_summary()
    assert loaded.skills == policy.skills and loaded.kvm_active_skills().tolist() == [True, False, True]
    assert [s.gated for s in loaded.skills] == [False, False, True]  # the failure's knowledge-gap skill
    batch = make_batch(policy.config, task=EGG, with_action=False)
    assert torch.equal(loaded.predict_action_chunk(batch), policy.predict_action_chunk(batch))
    for name in ("sigma2", "tau", "gate", "energy", "validity", "skill_weight"):
        a, b = (
            torch.as_tensor(getattr(policy.kvm_telemetry, name)),
            torch.as_tensor(getattr(loaded.kvm_telemetry, name)),
        )
        assert torch.equal(torch.nan_to_num(a), torch.nan_to_num(b)), name


def test_learning_continues_identically_after_a_round_trip(make_busy_policy, attempt, tmp_path) -> None:
    policy = make_busy_policy()
    policy.save_pretrained(tmp_path)
    loaded = CodaKvmPolicy.from_pretrained(tmp_path)
    for p in (policy, loaded):
        torch.manual_seed(7)
        p.kvm_feedback("failure", attempt(p, EGG, steps=4, seed=9), gradient_steps=3)
    for key, value in policy.state_dict().items():
        assert torch.equal(value, loaded.state_dict()[key]), key


@pytest.mark.slow
def test_lerobot_train_resume_restores_the_kvm_memory(tmp_path) -> None:
    """The counts of the KVM's buffers continue across `--resume=true` instead of restarting from zero."""
    from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, record_dataset

    spec = RecordingSpec(name="tiny", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 2)])
    record_dataset(spec, tmp_path / "data", repo_id="local/tiny", progress=False)
    env = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    bin_dir = Path(sys.executable).parent
    common = ["--policy.push_to_hub=false", "--policy.device=cpu", "--num_workers=0", "--wandb.enable=false"]
    cmd = [
        str(bin_dir / "lerobot-train"),
        "--policy.type=coda_kvm",
        "--dataset.repo_id=local/tiny",
        f"--dataset.root={tmp_path / 'data'}",
        f"--output_dir={tmp_path / 'train'}",
        "--steps=2",
        "--save_freq=2",
        "--batch_size=4",
        "--log_freq=1",
        "--policy.kvm.gate_window=64",
        *common,
    ]
    subprocess.run(cmd, cwd=tmp_path, env=env, check=True, capture_output=True, timeout=900)
    config = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    resume = [str(bin_dir / "lerobot-train"), f"--config_path={config}", "--resume=true", "--steps=4"]
    subprocess.run(resume, cwd=tmp_path, env=env, check=True, capture_output=True, timeout=900)
    first = load_file(tmp_path / "train" / "checkpoints" / "000002" / "pretrained_model" / "model.safetensors")
    second = load_file(tmp_path / "train" / "checkpoints" / "000004" / "pretrained_model" / "model.safetensors")
    assert int(first["kvm.gate.window.count"]) == 8 and int(second["kvm.gate.window.count"]) == 16
    assert int(first["kvm.safe_offline.count"]) == 8 and int(second["kvm.safe_offline.count"]) == 16
    assert first["kvm.gate.window.data"].shape == (64, second["kvm.gate.window.data"].shape[1])
    assert (
        torch.equal(first["kvm.labels.table"], second["kvm.labels.table"])
        and (first["kvm.labels.table"][:2] >= 0).all()
    )


def test_a_checkpoint_with_non_finite_weights_is_refused_by_name(make_policy, tmp_path) -> None:
    from safetensors.torch import save_file

    make_policy().save_pretrained(tmp_path)
    state = load_file(tmp_path / "model.safetensors")
    key = "kvm.energy.net.0.weight"
    state[key][0, 0] = float("nan")
    save_file(state, tmp_path / "model.safetensors")
    with pytest.raises(ValueError, match=rf"non-finite weights in \['{key}'\]"):
        CodaKvmPolicy.from_pretrained(tmp_path)

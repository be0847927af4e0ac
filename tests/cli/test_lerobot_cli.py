"""The real `lerobot-train` / `lerobot-eval` discover `coda_kvm` and `kvm_obsolescence` with no plugin flag."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, record_dataset

BIN = Path(sys.executable).parent
pytestmark = pytest.mark.slow


def run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"{cmd[0]} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}"
    return proc


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("cli")
    spec = RecordingSpec(name="tiny", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 2)])
    record_dataset(spec, work / "data", repo_id="local/tiny", progress=False)
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=coda_kvm",
            "--dataset.repo_id=local/tiny",
            f"--dataset.root={work / 'data'}",
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            f"--output_dir={work / 'train'}",
            "--steps=4",
            "--save_freq=2",
            "--batch_size=4",
            "--num_workers=0",
            "--log_freq=1",
            "--wandb.enable=false",
        ],
        work,
    )
    return work


def test_train_writes_a_hub_layout_checkpoint(trained):
    ckpt = trained / "train" / "checkpoints" / "last" / "pretrained_model"
    names = {p.name for p in ckpt.iterdir()}
    assert {"config.json", "model.safetensors", "train_config.json"} <= names
    assert any(n.startswith("policy_preprocessor") for n in names)
    assert any(n.startswith("policy_postprocessor") for n in names)
    assert json.loads((ckpt / "config.json").read_text())["type"] == "coda_kvm"


def test_resume_continues_the_checkpoint(trained):
    config = trained / "train" / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    run([str(BIN / "lerobot-train"), f"--config_path={config}", "--resume=true", "--steps=6"], trained)
    assert (trained / "train" / "checkpoints" / "000006" / "pretrained_model" / "model.safetensors").exists()


def test_from_pretrained_restores_every_tensor_bit_identically(trained):
    from lerobot_kvm.policy import CodaKvmPolicy

    ckpt = trained / "train" / "checkpoints" / "000004" / "pretrained_model"
    policy = CodaKvmPolicy.from_pretrained(ckpt)
    saved = load_file(ckpt / "model.safetensors")
    state = policy.state_dict()
    assert set(saved) == set(state)
    for key, value in saved.items():
        assert torch.equal(state[key], value), key


def test_eval_writes_per_scenario_results(trained):
    ckpt = trained / "train" / "checkpoints" / "last" / "pretrained_model"
    out = trained / "eval"
    run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={ckpt}",
            "--env.type=kvm_obsolescence",
            "--env.task=egg_vs_stone",
            "--env.episode_length=10",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={out}",
        ],
        trained,
    )
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2
    assert list(info["per_group"]) == ["egg_vs_stone"]
    assert len(info["per_task"][0]["metrics"]["sum_rewards"]) == 2  # per episode: 1 success, -1 catastrophe
    assert 0.0 <= info["overall"]["pc_success"] <= 100.0


def test_train_from_a_checkpoint_with_a_new_skill_name_grows_the_pool(trained):
    """Task-incremental `lerobot-train`: the next task starts from the previous checkpoint in new components."""
    from lerobot_kvm.policy import CodaKvmPolicy

    previous = trained / "train" / "checkpoints" / "000004" / "pretrained_model"
    spec = RecordingSpec(name="next", items=[RecordItem("egg_vs_stone", "prior", "gentle_grasp", 2, "skill")])
    record_dataset(spec, trained / "next_data", repo_id="local/next", progress=False)
    run(
        [
            str(BIN / "lerobot-train"),
            f"--policy.path={previous}",
            "--policy.skill_name=gentle_grasp",
            "--dataset.repo_id=local/next",
            f"--dataset.root={trained / 'next_data'}",
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            f"--output_dir={trained / 'stage1'}",
            "--steps=2",
            "--save_freq=2",
            "--batch_size=4",
            "--num_workers=0",
            "--wandb.enable=false",
        ],
        trained,
    )
    before = CodaKvmPolicy.from_pretrained(previous)
    after = CodaKvmPolicy.from_pretrained(trained / "stage1" / "checkpoints" / "last" / "pretrained_model")
    assert [s.name for s in after.skills] == [before.skills[0].name, "gentle_grasp"]
    old, new = before.pool.tasks[0].state_dict(), after.pool.tasks[0].state_dict()
    assert all(torch.equal(v, new[k]) for k, v in old.items())
    assert torch.equal(before.query_fingerprint, after.query_fingerprint)


def test_overhead_after_failures_given_as_feedback(trained):
    """`lerobot-kvm overhead --failures`: attempts on shifted variants, their outcomes fed back, then the timing."""
    ckpt = trained / "train" / "checkpoints" / "last" / "pretrained_model"
    out = trained / "overhead.json"
    args = ["--steps=2", "--block=1", "--warmup=1", "--failures=egg_vs_stone", f"--json={out}"]
    run([str(BIN / "lerobot-kvm"), "overhead", f"--policy-path={ckpt}", *args], trained)
    result = json.loads(out.read_text())
    [given] = result["feedback"]
    assert given["scenario"] == "egg_vs_stone" and given["steps"] > 0
    assert given["outcome"] in ("success", "failure", "catastrophe")
    assert (result["failure_memory"] > 0) == (given["outcome"] != "success")
    assert result["calls_per_mode"] == 2 and result["paired_ratio_gate_open"] > 0

"""`coda_kvm` on a LeRobot dataset that is not ours: one camera of another size, a state, an action, no context.

The dataset is made with LeRobot's own `LeRobotDataset.create` and trained through the real `lerobot-train`; the
checkpoint must reload bit-identically and act, through its saved processors, on a frame of that dataset.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from safetensors.torch import load_file

from lerobot_kvm.policy import CodaKvmPolicy

pytestmark = pytest.mark.slow

BIN = Path(sys.executable).parent
IMAGE = "observation.image"  # LeRobot's single-camera key, not the suite's `observation.images.front`
HEIGHT, WIDTH = 120, 160  # larger than the backbone's input: scaled to 72x96
TINY = [
    "--policy.vision_channels=[8,8,8]",
    "--policy.dim_model=32",
    "--policy.n_layers=2",
    "--policy.n_heads=2",
    "--policy.dim_feedforward=64",
    "--policy.prompt_length=4",
    "--policy.prompt_layers=2",
    "--policy.pool_size=6",
    "--policy.n_tasks=3",
    "--policy.chunk_size=4",
    "--policy.n_action_steps=2",
]


def make_plain_dataset(root: Path) -> None:
    """Two episodes of a square moving across the image, the state its position, the action its velocity."""
    features = {
        IMAGE: {"dtype": "image", "shape": (HEIGHT, WIDTH, 3), "names": ["height", "width", "channels"]},
        "observation.state": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "action": {"dtype": "float32", "shape": (2,), "names": ["vx", "vy"]},
    }
    ds = LeRobotDataset.create(repo_id="local/plain", fps=10, features=features, root=root, use_videos=False)
    rng = np.random.default_rng(0)
    for _episode in range(2):
        position = rng.uniform(20, 100, size=2)
        for _ in range(12):
            velocity = rng.normal(0, 2, size=2)
            image = np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)
            y, x = position.astype(int)
            image[y : y + 10, x : x + 10] = 255
            ds.add_frame(
                {
                    IMAGE: image,
                    "observation.state": position.astype(np.float32),
                    "action": velocity.astype(np.float32),
                    "task": "push the square",
                }
            )
            position = np.clip(position + velocity, 0, 100)
        ds.save_episode()
    ds.finalize()


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    work = tmp_path_factory.mktemp("plain")
    make_plain_dataset(work / "data")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    cmd = [
        str(BIN / "lerobot-train"),
        "--policy.type=coda_kvm",
        "--dataset.repo_id=local/plain",
        f"--dataset.root={work / 'data'}",
        "--policy.push_to_hub=false",
        "--policy.device=cpu",
        f"--output_dir={work / 'train'}",
        "--steps=3",
        "--save_freq=3",
        "--batch_size=4",
        "--num_workers=0",
        "--wandb.enable=false",
        *TINY,
    ]
    proc = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"lerobot-train failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}"
    return work / "train" / "checkpoints" / "last" / "pretrained_model", proc


def test_training_says_once_that_the_context_is_the_state(trained):
    _, proc = trained
    output = proc.stdout + proc.stderr
    assert output.count("no 'observation.context' input feature") == 1
    assert "Traceback" not in output


def test_the_checkpoint_reloads_bit_identically_and_acts(trained, tmp_path):
    ckpt, _ = trained
    policy = CodaKvmPolicy.from_pretrained(ckpt)
    assert policy.config.context_key == "observation.state"
    assert policy.config.image_shape == (3, 72, 96)
    saved, state = load_file(ckpt / "model.safetensors"), policy.state_dict()
    assert set(saved) == set(state)
    assert all(torch.equal(state[key], value) for key, value in saved.items())

    policy.save_pretrained(tmp_path)  # a second round trip keeps every tensor
    resaved = load_file(tmp_path / "model.safetensors")
    assert all(torch.equal(resaved[key], value) for key, value in saved.items())

    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(ckpt))
    frame = LeRobotDataset("local/plain", root=ckpt.parents[3] / "data")[5]
    observation = {k: v for k, v in frame.items() if k in (IMAGE, "observation.state")} | {"task": frame["task"]}
    for _ in range(3):  # past one chunk of n_action_steps=2
        action = post(policy.select_action(pre(observation)))
        assert action.shape == (1, 2) and torch.isfinite(action).all()

"""A tiny skill pool grown once per session with the real `train-continual` (every method of `cl_tiny.json`,
each stage under torchrun with two processes): the continual-learning test checks it, the benchmark test
starts from it."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
CLI = str(Path(sys.executable).parent / "lerobot-kvm")
LAUNCHER = "--launcher=torchrun --standalone --nproc_per_node=2"  # every stage trains in two processes (gloo)


@pytest.fixture(scope="session")
def cli_env() -> dict[str, str]:
    return {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}


@pytest.fixture(scope="session")
def tiny_pool(tmp_path_factory, cli_env) -> dict:
    base = tmp_path_factory.mktemp("tiny_pool")
    cmd = [
        CLI,
        "train-continual",
        f"--config={CONFIGS / 'cl_tiny.json'}",
        f"--output-dir={base / 'bench' / 'pool'}",
        f"--dataset-root={base / 'data'}",
        LAUNCHER,
    ]
    proc = subprocess.run(cmd, env=cli_env, capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    return {
        "base": base,
        "out": base / "bench" / "pool",
        "data": base / "data",
        "cmd": cmd,
        "env": cli_env,
        "cli": CLI,
        "launcher": LAUNCHER,
    }

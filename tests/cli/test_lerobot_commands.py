"""The `lerobot-train` command lines the benchmark and `train-continual` build."""

from pathlib import Path

from lerobot_kvm.cli.lerobot_commands import train_command


def _flag(cmd: list[str], name: str) -> str:
    return next(arg.split("=", 1)[1] for arg in cmd if arg.startswith(f"--{name}="))


def test_a_single_process_run_loads_batches_in_a_worker():
    cmd = train_command(Path("data"), "local/x", Path("out"), steps=10, batch_size=4, seed=0)
    assert Path(cmd[0]).name == "lerobot-train"
    assert _flag(cmd, "num_workers") == "1"


def test_under_a_launcher_each_rank_loads_its_own_batches():
    launcher = ["torchrun", "--standalone", "--nproc_per_node=2"]
    cmd = train_command(Path("data"), "local/x", Path("out"), 10, 4, 0, launcher=launcher)
    assert Path(cmd[0]).name == "torchrun" and cmd[1:3] == launcher[1:]
    assert Path(cmd[3]).name == "lerobot-train"
    assert _flag(cmd, "num_workers") == "0"

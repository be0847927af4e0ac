"""The `lerobot-train` command lines the benchmark and `train-continual` build, and how they are run."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_kvm.benchmark import lerobot_commands
from lerobot_kvm.benchmark.lerobot_commands import eval_command, program_name, run_logged, train_command


def _flag(cmd: list[str], name: str) -> str:
    return next(arg.split("=", 1)[1] for arg in cmd if arg.startswith(f"--{name}="))


def test_a_single_process_run_loads_batches_in_a_worker_and_leaves_it_a_core(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(lerobot_commands, "available_cores", lambda: 2)
    cmd = train_command(Path("data"), "local/x", Path("out"), steps=10, batch_size=4, seed=0)
    assert cmd[:2] == ["env", "OMP_NUM_THREADS=1"] and Path(cmd[2]).name == "lerobot-train"
    assert program_name(cmd) == "lerobot-train"
    assert _flag(cmd, "num_workers") == "1"
    monkeypatch.setattr(lerobot_commands, "available_cores", lambda: 16)
    assert train_command(Path("data"), "local/x", Path("out"), 10, 4, 0)[1] == "OMP_NUM_THREADS=15"


def test_a_users_thread_count_is_left_alone(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    cmd = train_command(Path("data"), "local/x", Path("out"), steps=10, batch_size=4, seed=0)
    assert Path(cmd[0]).name == "lerobot-train"


def test_under_a_launcher_each_rank_loads_its_own_batches():
    launcher = ["torchrun", "--standalone", "--nproc_per_node=2"]
    cmd = train_command(Path("data"), "local/x", Path("out"), 10, 4, 0, launcher=launcher)
    assert Path(cmd[0]).name == "torchrun" and cmd[1:3] == launcher[1:]
    assert Path(cmd[3]).name == "lerobot-train" and program_name(cmd) == "torchrun"
    assert _flag(cmd, "num_workers") == "0"


def test_training_and_evaluation_run_the_policy_on_the_named_device():
    for device in ("cpu", "cuda"):
        kwargs = {"device": device} if device != "cpu" else {}  # cpu by default
        assert _flag(train_command(Path("data"), "local/x", Path("out"), 10, 4, 0, **kwargs), "policy.device") == device
        assert _flag(eval_command(Path("p"), Path("out"), "book", "prior", 2, 0, **kwargs), "policy.device") == device


def test_a_run_saves_at_its_end_or_every_save_every_steps():
    assert _flag(train_command(Path("data"), "local/x", Path("out"), 500, 4, 0), "save_freq") == "500"
    assert _flag(train_command(Path("data"), "local/x", Path("out"), 500, 4, 0, save_every=100), "save_freq") == "100"


def _alive(pid: int) -> bool:
    """Running (a zombie waiting to be reaped has finished)."""
    stat = Path(f"/proc/{pid}/stat")
    try:
        return stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_a_command_that_outlives_its_completed_work_is_stopped_with_its_children(tmp_path, monkeypatch):
    """A launcher whose rank hangs after the final checkpoint: the stage counts as finished, nothing is left."""
    monkeypatch.setattr(lerobot_commands, "POLL_S", 0.1)
    marker, child = tmp_path / "done", tmp_path / "child.pid"
    hang = (
        "import pathlib, signal, subprocess, sys, time;"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN);"  # a rank that ignores SIGTERM
        f"p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)']);"
        f"pathlib.Path({str(child)!r}).write_text(str(p.pid));"
        f"pathlib.Path({str(marker)!r}).touch(); time.sleep(600)"
    )
    log = tmp_path / "stage.log"
    start = time.monotonic()
    run_logged([sys.executable, "-c", hang], log, done=marker.exists, grace_s=0.5)
    assert time.monotonic() - start < 30
    assert "after its work was complete: stopped" in log.read_text()
    pid = int(child.read_text())
    deadline = time.monotonic() + 5
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(pid)


def test_a_failing_command_raises_with_its_log_tail(tmp_path):
    log = tmp_path / "stage.log"
    with pytest.raises(RuntimeError, match="exit code 3(.|\n)*boom"):
        run_logged([sys.executable, "-c", "print('boom'); raise SystemExit(3)"], log, done=lambda: False)


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGKILL])
def test_a_killed_pipeline_stops_the_command_it_started(tmp_path, stop):
    """`kill` of `lerobot-kvm` reaches the lerobot-train it runs, although that runs in a session of its own: a
    SIGTERM through the pipeline's handler, a SIGKILL (no handler runs) through the child's parent-death signal."""
    if stop == signal.SIGKILL and not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    child = tmp_path / "child.pid"
    sleeper = f"import os, pathlib, time; pathlib.Path({str(child)!r}).write_text(str(os.getpid())); time.sleep(600)"
    pipeline = (
        "import pathlib, sys\n"
        "from lerobot_kvm.cli.main import exit_on_sigterm\n"
        "from lerobot_kvm.benchmark.lerobot_commands import run_logged\n"
        "exit_on_sigterm()\n"
        f"run_logged([sys.executable, '-c', {sleeper!r}], pathlib.Path({str(tmp_path / 'stage.log')!r}))\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", pipeline])
    deadline = time.monotonic() + 120
    while not child.exists() or not child.read_text():
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    proc.send_signal(stop)
    assert proc.wait(timeout=60) == (128 + signal.SIGTERM if stop == signal.SIGTERM else -signal.SIGKILL)
    pid = int(child.read_text())
    deadline = time.monotonic() + 30
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(pid)


def _workers_of(pid: int) -> list[int]:
    """The spawned multiprocessing workers among a process's children (Linux /proc)."""
    children = [int(c) for t in Path(f"/proc/{pid}/task").iterdir() for c in (t / "children").read_text().split()]
    return [c for c in children if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGKILL])
def test_a_killed_benchmark_stops_its_worker_processes(stop):
    """The benchmark's (method, run) workers end with it: a SIGTERM's exit terminates them, a SIGKILL reaches them
    through their parent-death signal. A worker left running would write into the output directory of the next run."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal and /proc are Linux's")
    pipeline = (
        "import time\n"
        "from lerobot_kvm.cli.main import exit_on_sigterm\n"
        "from lerobot_kvm.benchmark.protocol import in_workers\n"
        "exit_on_sigterm()\n"
        "for _ in in_workers(time.sleep, [(600,)], 1):\n"
        "    pass\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", pipeline])
    deadline = time.monotonic() + 120
    while not _workers_of(proc.pid):
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    time.sleep(0.5)  # the worker has run its initializer and taken the job
    (worker,) = _workers_of(proc.pid)
    proc.send_signal(stop)
    proc.wait(timeout=60)
    deadline = time.monotonic() + 30
    while _alive(worker) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(worker)

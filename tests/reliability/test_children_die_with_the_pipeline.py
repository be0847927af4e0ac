"""A pipeline killed by any signal, SIGKILL included, takes the trainer it started with it."""

import subprocess
import sys
import time

import pytest

from lerobot_kvm.datasets.ownership import process_alive


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_sigkill_of_the_pipeline_stops_its_child(tmp_path):
    pid_file, log = tmp_path / "child.pid", tmp_path / "child.log"
    child = f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); time.sleep(300)"
    pipeline = (
        "import sys\n"
        "from pathlib import Path\n"
        "from lerobot_kvm.benchmark.lerobot_commands import run_logged\n"
        f"run_logged([sys.executable, '-c', {child!r}], log=Path({str(log)!r}))\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", pipeline])
    deadline = time.monotonic() + 120
    while not pid_file.exists() or not pid_file.read_text():
        assert time.monotonic() < deadline and parent.poll() is None, "the child never started"
        time.sleep(0.2)
    child_pid = int(pid_file.read_text())
    parent.kill()  # SIGKILL: no handler of the pipeline runs
    parent.wait()
    deadline = time.monotonic() + 30
    while process_alive(child_pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    alive = process_alive(child_pid)
    if alive:
        subprocess.run(["kill", "-9", str(child_pid)])
    assert not alive, "the child outlived its pipeline"

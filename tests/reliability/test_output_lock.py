"""One run at a time in an output directory: a second one is refused with the holder's pid, a dead one's lock
is taken over, and the lock goes when the run ends."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_kvm.benchmark.lock import LOCK, hold

QUICK = Path(__file__).resolve().parents[2] / "configs" / "benchmark_quick.json"


@pytest.fixture
def other_run():
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    yield proc.pid
    proc.kill()
    proc.wait()


def test_a_second_run_is_refused_with_the_holders_pid(tmp_path, cli, other_run):
    out = tmp_path / "bench"
    out.mkdir()
    (out / LOCK).write_text(str(other_run))
    code, stderr = cli("benchmark", f"--config={QUICK}", f"--output-dir={out}")
    assert code == 2 and f"in use by another run (pid {other_run})" in stderr
    assert sorted(p.name for p in out.iterdir()) == [LOCK]  # nothing of the refused run, the holder's lock kept


def test_a_killed_runs_lock_is_taken_over_and_released(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / LOCK).write_text(str(dead.pid))
    with hold(tmp_path):
        assert (tmp_path / LOCK).read_text() == str(os.getpid())
        with pytest.raises(ValueError, match="in use by another run"):  # as another process would see it
            (tmp_path / LOCK).write_text(str(os.getppid()))
            with hold(tmp_path):
                pass
        (tmp_path / LOCK).write_text(str(os.getpid()))
    assert not (tmp_path / LOCK).exists()

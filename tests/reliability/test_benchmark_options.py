"""The benchmark's command-line overrides are checked with its config, before any pool is trained."""

import subprocess
import sys
from pathlib import Path

import pytest

CLI = str(Path(sys.executable).parent / "lerobot-kvm")
QUICK = Path(__file__).resolve().parents[2] / "configs" / "benchmark_quick.json"


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ("--methods=coda_kvm,bogus", "unknown methods ['bogus']"),
        ("--methods=", "a benchmark needs methods and scenarios"),
        ("--runs=0", "runs must be >= 1, got 0"),
        ("--runs=-2", "runs must be >= 1, got -2"),
        ("--workers=0", "workers must be >= 1"),
    ],
)
def test_a_bad_override_fails_at_once_and_writes_nothing(tmp_path, option, message):
    out = tmp_path / "bench"
    result = subprocess.run(
        [CLI, "benchmark", f"--config={QUICK}", f"--output-dir={out}", option],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()  # nothing written: the corrected rerun is not blocked

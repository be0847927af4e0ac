"""The benchmark's command-line overrides are checked with its config, before any pool is trained."""

from pathlib import Path

import pytest

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
def test_a_bad_override_fails_at_once_and_writes_nothing(tmp_path, cli, option, message):
    out = tmp_path / "bench"
    code, stderr = cli("benchmark", f"--config={QUICK}", f"--output-dir={out}", option)
    assert code == 2 and message in stderr
    assert not out.exists()  # nothing written: the corrected rerun is not blocked

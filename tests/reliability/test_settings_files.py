"""A faulty recording spec, sequence or benchmark config is refused with the file and the key, nothing else."""

import json
from pathlib import Path

import pytest

from lerobot_kvm.benchmark.continual import SequenceConfig
from lerobot_kvm.benchmark.protocol import BenchmarkConfig
from lerobot_kvm.datasets.recorder import RecordingSpec

SEQUENCE = {
    "name": "s",
    "tasks": [{"scenario": "egg_vs_stone"}],
    "methods": [{"name": "coda_kvm", "policy": "coda_kvm"}],
}


def _write(tmp_path, content) -> str:
    path = tmp_path / "settings.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return str(path)


@pytest.mark.parametrize("reader", [SequenceConfig.from_json, BenchmarkConfig.from_json, RecordingSpec.from_json])
def test_malformed_json_names_the_file(tmp_path, reader):
    path = _write(tmp_path, '{"name": "x",')
    with pytest.raises(ValueError, match=rf"{path}: not a readable JSON file"):
        reader(path)
    with pytest.raises(ValueError, match=rf"{path}: expected a JSON object"):
        reader(_write(tmp_path, "[1, 2]"))


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ({**SEQUENCE, "taks": []}, r"settings.json: unknown keys \['taks'\]"),
        ({**SEQUENCE, "tasks": [{"scenario": "egg_vs_stone", "varient": "prior"}]}, r"tasks\[0\]: unknown keys"),
        ({**SEQUENCE, "methods": [{"policy": "coda_kvm"}]}, r"methods\[0\]: .*name"),
        ({**SEQUENCE, "methods": [{"name": "m", "policy": "coda_kvm", "lr": 1}]}, r"methods\[0\]: unknown keys"),
        ({**SEQUENCE, "tasks": [{"scenario": "eggs"}]}, r"tasks\[0\]: unknown scenario 'eggs'"),
        ({**SEQUENCE, "tasks": {"scenario": "egg_vs_stone"}}, r"'tasks' must be a list"),
    ],
)
def test_sequence_faults_name_the_key(tmp_path, content, message):
    with pytest.raises(ValueError, match=message):
        SequenceConfig.from_json(_write(tmp_path, content))


def test_recording_spec_faults_name_the_key(tmp_path):
    spec = {
        "name": "r",
        "items": [{"scenario": "egg_vs_stone", "variant": "prior", "skill": "firm_grasp", "epsiodes": 2}],
    }
    with pytest.raises(ValueError, match=r"items\[0\]: unknown keys \['epsiodes'\]"):
        RecordingSpec.from_json(_write(tmp_path, spec))


def test_an_unknown_benchmark_key_is_named(tmp_path):
    quick = json.loads((Path(__file__).resolve().parents[2] / "configs" / "benchmark_quick.json").read_text())
    with pytest.raises(ValueError, match=r"settings.json: unknown keys \['typo_key'\]"):
        BenchmarkConfig.from_json(_write(tmp_path, {**quick, "typo_key": 1}))


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.json: no such file"):
        BenchmarkConfig.from_json(tmp_path / "nothing.json")

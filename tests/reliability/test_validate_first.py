"""Settings and dataset roots are checked before anything is written, so a refused run never blocks its own fix.

Each case runs `lerobot-kvm` in-process, as the console script does, and expects one error line naming the file,
the key or the dataset fault; then an empty working directory (no output directory, no `settings.json`); then the
corrected rerun reaches its first `lerobot-train` (stopped there: the test trains nothing).
"""

import json
import shutil
from dataclasses import asdict
from pathlib import Path

import pytest

from lerobot_kvm.benchmark import continual
from lerobot_kvm.cli import walkthrough
from lerobot_kvm.cli.main import main
from lerobot_kvm.datasets.recorder import RecordingSpec, record_dataset

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
TASK = {"scenario": "egg_vs_stone", "variant": "prior", "skill": "prior", "instruction": "variant"}
SEQUENCE = {"name": "s", "episodes_per_task": 1, "tasks": [TASK], "methods": [{"name": "m", "steps_per_stage": 1}]}


class TrainingReached(Exception):
    """Raised where a run would start `lerobot-train`: it got past every check."""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """One episode of the walkthrough's spec: the sequence's task, and the walkthrough's dataset at --episodes=1."""
    spec = RecordingSpec.from_json(walkthrough.DEFAULT_SPEC)
    spec.items[0].episodes = 1
    root = tmp_path_factory.mktemp("recorded") / "data"
    record_dataset(spec, root, progress=False)
    return root


@pytest.fixture
def work(tmp_path, monkeypatch) -> Path:
    """An empty working directory where starting `lerobot-train` is `TrainingReached`."""

    def reached(*_args: object, **_kwargs: object) -> None:
        raise TrainingReached

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(continual, "run_logged", reached)
    monkeypatch.setattr(walkthrough, "run_logged", reached)
    return tmp_path


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one error line of a refused command."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def _write(path: Path, content: dict) -> str:
    path.write_text(json.dumps(content))
    return str(path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"episodes_per_task": -1}, "cl.json: episodes_per_task must be >= 1, got -1"),
        ({"episodes_per_task": "2"}, "cl.json: episodes_per_task must be >= 1, got '2'"),
        ({"pretrain_episodes_per_task": 0}, "cl.json: pretrain_episodes_per_task must be >= 1, got 0"),
        ({"eval_episodes": 0}, "cl.json: eval_episodes must be >= 1, got 0"),
        ({"methods": [{"name": "m", "steps_per_stage": 0}]}, "cl.json: methods[0]: steps_per_stage must be >= 1"),
        ({"methods": [{"name": "m", "batch_size": -4}]}, "cl.json: methods[0]: batch_size must be >= 1, got -4"),
        ({"methods": [{"name": "m", "args": "--policy.x=1"}]}, "methods[0]: args must be a list of command-line"),
        ({"tasks": [{**TASK, "variant": "melted"}]}, "tasks[0]: egg_vs_stone: unknown variant 'melted' (have"),
        ({"tasks": [{**TASK, "skill": "juggle"}]}, "tasks[0]: task egg_vs_stone: skill must be 'prior' or 'safe'"),
        ({"tasks": [{**TASK, "speed": 2}]}, "cl.json: tasks[0]: unknown keys ['speed']; accepted: ["),
    ],
)
def test_a_sequence_fault_names_file_and_key_and_leaves_nothing(work, capsys, recorded, change, message):
    """Row 24: before, `episodes_per_task: -1` was refused by the recorder, naming neither file nor key, after
    `out/settings.json` was written."""
    config = _write(work / "cl.json", {**SEQUENCE, **change})
    argv = ["train-continual", f"--config={config}", "--output-dir=out", f"--dataset-root={recorded}"]
    assert message in _refused(argv, capsys)
    assert sorted(p.name for p in work.iterdir()) == ["cl.json"]  # no output directory, no settings
    _write(work / "cl.json", SEQUENCE)
    with pytest.raises(TrainingReached):
        main(argv)


@pytest.mark.parametrize("command", ["train-continual", "benchmark"])
def test_a_misspelt_device_is_refused_before_writing(work, capsys, recorded, command):
    """The device is one of the settings a rerun must repeat: kept after a typo, it refused the corrected rerun."""
    sequence = _write(work / "cl.json", SEQUENCE)
    common = ["--device=cdua", f"--dataset-root={recorded}"]
    if command == "benchmark":
        argv = [*_benchmark(work, str(CONFIGS / "cl_quick.json")), *common]
    else:
        argv = ["train-continual", f"--config={sequence}", "--output-dir=out", *common]
    assert "device 'cdua' is not a torch device (Expected one of cpu, cuda" in _refused(argv, capsys)
    assert not (work / "out").exists() and not (work / "bench").exists()


def _damage(root: Path, fault: str) -> None:
    if fault == "truncated info":
        info = root / "meta" / "info.json"
        info.write_text(info.read_text()[:40])
    else:
        next((root / "data").rglob("*.parquet")).write_bytes(b"junk")


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("empty", "dataset root bad is empty"),
        ("a file", "dataset root bad does not exist or is not a directory"),
        ("truncated info", "bad/meta/info.json: not a readable JSON file"),
        ("corrupt parquet", "is not a readable parquet file"),
        ("another task", "dataset bad has no episode of task chip_bag.firm_grasp"),
    ],
)
def test_a_bad_dataset_root_leaves_nothing_that_blocks_another_root(work, capsys, recorded, fault, message):
    """Rows 15-18: before, `out/settings.json` was written first and named the bad root, so the rerun with a good
    `--dataset-root` was refused as made with other settings."""
    config = _write(work / "cl.json", SEQUENCE)
    bad = work / "bad"
    if fault == "empty":
        bad.mkdir()
    elif fault == "a file":
        bad.write_text("not a dataset")
    else:
        shutil.copytree(recorded, bad)
        if fault == "another task":
            config = _write(work / "cl.json", {**SEQUENCE, "tasks": [{"scenario": "chip_bag"}]})
        else:
            _damage(bad, fault)
    argv = ["train-continual", f"--config={config}", "--output-dir=out"]
    assert message in _refused([*argv, "--dataset-root=bad"], capsys)
    assert not (work / "out").exists()
    _write(work / "cl.json", SEQUENCE)
    with pytest.raises(TrainingReached):
        main([*argv, f"--dataset-root={recorded}"])
    assert json.loads((work / "out" / "settings.json").read_text())["dataset_root"] == str(recorded)


def _benchmark(work: Path, sequence: str) -> list[str]:
    """`lerobot-kvm benchmark` with the quick config over `sequence`."""
    quick = json.loads((CONFIGS / "benchmark_quick.json").read_text())
    config = _write(work / "b.json", {**quick, "sequence": sequence})
    return ["benchmark", f"--config={config}", "--output-dir=bench", "--workers=1"]


def test_the_benchmark_checks_its_pools_dataset_before_writing(work, capsys):
    (work / "empty").mkdir()
    argv = _benchmark(work, str(CONFIGS / "cl_quick.json"))
    assert "dataset root empty is empty" in _refused([*argv, "--dataset-root=empty"], capsys)
    assert sorted(p.name for p in work.iterdir()) == ["b.json", "empty"]  # no benchmark settings, no pool


def test_the_benchmark_names_its_sequences_bad_count(work, capsys):
    argv = _benchmark(work, _write(work / "cl.json", {**SEQUENCE, "episodes_per_task": -1}))
    assert "cl.json: episodes_per_task must be >= 1, got -1" in _refused(argv, capsys)
    assert sorted(p.name for p in work.iterdir()) == ["b.json", "cl.json"]


@pytest.mark.parametrize(
    ("change", "message"),
    [({"fps": 0}, "s.json: fps must be >= 1, got 0"), ({"image_size": -96}, "s.json: image_size must be >= 1")],
)
def test_a_recording_spec_size_is_refused_before_recording(work, capsys, change, message):
    spec = asdict(RecordingSpec.from_json(walkthrough.DEFAULT_SPEC)) | change
    path = _write(work / "s.json", spec)
    assert message in _refused(["record", f"--spec={path}", "--root=data"], capsys)
    assert sorted(p.name for p in work.iterdir()) == ["s.json"]  # no dataset, no temporary root


def test_the_walkthrough_checks_a_reused_dataset_before_writing(work, capsys, recorded):
    (work / "empty").mkdir()
    argv = ["walkthrough", "--output-dir=out", "--episodes=1"]
    assert "dataset root empty is empty" in _refused([*argv, "--dataset-root=empty"], capsys)
    assert sorted(p.name for p in work.iterdir()) == ["empty"]
    with pytest.raises(TrainingReached):
        main([*argv, f"--dataset-root={recorded}"])

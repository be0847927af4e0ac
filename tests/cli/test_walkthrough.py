"""`lerobot-kvm walkthrough`'s wiring: the device reaches both tools, and a rerun never reuses a dataset or a
policy made with other settings (the real tools run in `test_lerobot_cli`)."""

import json
from dataclasses import asdict

import pytest

from lerobot_kvm.cli import walkthrough
from lerobot_kvm.cli.main import build_parser
from lerobot_kvm.datasets.labels import LABELS_FILE
from lerobot_kvm.datasets.recorder import RecordingSpec


@pytest.fixture
def commands(monkeypatch):
    """Every command the walkthrough runs; a training run leaves its checkpoint, an evaluation its results."""
    ran = []

    def run_logged(cmd, *args, **kwargs):
        ran.append(cmd)
        out = next(a.split("=", 1)[1] for a in cmd if a.startswith("--output_dir="))
        if any(a.endswith("lerobot-train") for a in cmd):
            (walkthrough.Path(out) / "checkpoints" / "last" / "pretrained_model").mkdir(parents=True)
        else:
            info = {
                "overall": {"pc_success": 50.0, "n_episodes": 2},
                "per_task": [{"metrics": {"sum_rewards": [1, -1]}}],
            }
            walkthrough.Path(out).mkdir(parents=True)
            (walkthrough.Path(out) / "eval_info.json").write_text(json.dumps(info))

    monkeypatch.setattr(walkthrough, "run_logged", run_logged)
    monkeypatch.setattr(walkthrough, "check_dataset", lambda root: {})  # the datasets here are labels only
    return ran


def _recorded(root, spec: RecordingSpec) -> None:
    labels = root / LABELS_FILE
    labels.parent.mkdir(parents=True)
    labels.write_text(json.dumps({"spec": asdict(spec), "episodes": []}))


def _walkthrough(tmp_path, *extra: str) -> int:
    args = build_parser("walkthrough").parse_args(
        ["walkthrough", f"--dataset-root={tmp_path / 'data'}", f"--output-dir={tmp_path / 'out'}", *extra]
    )
    return args.func(args)


def test_the_device_reaches_training_and_evaluation_and_the_same_rerun_reuses_the_policy(tmp_path, commands):
    spec = RecordingSpec.from_json(walkthrough.DEFAULT_SPEC)
    for item in spec.items:
        item.episodes = 2
    _recorded(tmp_path / "data", spec)
    assert _walkthrough(tmp_path, "--episodes=2", "--steps=3", "--device=cuda") == 0
    train, evaluate = commands
    assert "--policy.device=cuda" in train and "--policy.device=cuda" in evaluate and "--steps=3" in train
    _walkthrough(tmp_path, "--episodes=2", "--steps=3", "--device=cuda")
    assert len(commands) == 3  # evaluated again, not retrained

    with pytest.raises(ValueError, match=r"a walkthrough's policy made with other settings \(steps: 3 -> 4\).*--fresh"):
        _walkthrough(tmp_path, "--episodes=2", "--steps=4")
    _walkthrough(tmp_path, "--episodes=2", "--steps=4", "--fresh")
    assert "--steps=4" in commands[3]


def test_a_dataset_recorded_with_other_episodes_is_refused(tmp_path, commands):
    _recorded(tmp_path / "data", RecordingSpec.from_json(walkthrough.DEFAULT_SPEC))
    with pytest.raises(ValueError, match=r"recorded with other settings \(items\[0\]\.episodes: 40 -> 2\)"):
        _walkthrough(tmp_path, "--episodes=2")
    assert commands == []

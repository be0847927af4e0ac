import json

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_kvm.datasets import recorder
from lerobot_kvm.datasets.labels import load_label_vocab, load_labels
from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, record_dataset
from lerobot_kvm.envs.configuration_kvm_obsolescence import OBS_CONTEXT
from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import context_names


def tiny_spec() -> RecordingSpec:
    return RecordingSpec(
        name="tiny",
        items=[
            RecordItem("egg_vs_stone", "prior", "firm_grasp", 1),
            RecordItem("egg_vs_stone", "prior", "gentle_grasp", 1, instruction="skill"),
        ],
    )


def test_round_trip_through_lerobot_dataset(tmp_path):
    root = tmp_path / "tiny"
    summary = record_dataset(tiny_spec(), root, progress=False)
    assert summary["episodes"] == 2
    ds = LeRobotDataset("local/tiny", root=root)
    assert ds.num_episodes == 2
    frame = ds[0]
    assert frame["observation.images.front"].shape == (3, 96, 96)
    assert frame["observation.state"].shape == (6,) and frame["observation.context"].shape == (24,)
    assert frame["action"].shape == (5,)
    vocab = load_label_vocab(root)
    tasks = {ds[i]["task"] for i in range(len(ds))}
    assert tasks == {"pick up the stone", "gently pick up the stone"}
    skills = {vocab["skill"][int(ds[i]["label.skill"])] for i in range(len(ds))}
    assert skills == {"firm_grasp", "gentle_grasp"}
    assert all(vocab["outcome"][int(ds[i]["label.outcome"])] == "success" for i in range(len(ds)))
    assert torch.isfinite(frame["observation.context"]).all()
    episodes = load_labels(root)["episodes"]
    assert [e["skill"] for e in episodes] == ["firm_grasp", "gentle_grasp"]
    for e in episodes:
        first = ds[int(ds.meta.episodes["dataset_from_index"][e["episode_index"]])]
        assert vocab["skill"][int(first["label.skill"])] == e["skill"] and first["task"] == e["task"]


def test_recording_is_deterministic(tmp_path):
    spec = RecordingSpec(name="d", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 1)], seed=5)
    a = LeRobotDataset("local/d", root=tmp_path / "a") if record_dataset(spec, tmp_path / "a", progress=False) else None
    b = LeRobotDataset("local/d", root=tmp_path / "b") if record_dataset(spec, tmp_path / "b", progress=False) else None
    assert len(a) == len(b)
    for i in (0, len(a) - 1):
        torch.testing.assert_close(a[i]["action"], b[i]["action"], rtol=0, atol=0)
        torch.testing.assert_close(a[i]["observation.images.front"], b[i]["observation.images.front"], rtol=0, atol=0)


def test_failed_recording_leaves_nothing_behind(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = recorder._run_episode

    def crash_on_second(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(recorder, "_run_episode", crash_on_second)
    with pytest.raises(KeyboardInterrupt):
        record_dataset(tiny_spec(), tmp_path / "ds", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_existing_root_and_bad_specs_are_refused(tmp_path):
    (tmp_path / "ds").mkdir()
    with pytest.raises(FileExistsError):
        record_dataset(tiny_spec(), tmp_path / "ds", progress=False)
    with pytest.raises(ValueError, match="skill"):
        RecordItem("egg_vs_stone", "prior", "juggle", 1)
    with pytest.raises(ValueError, match="variant"):
        RecordItem("egg_vs_stone", "melted", "firm_grasp", 1)
    path = tmp_path / "spec.json"
    path.write_text(json.dumps({"name": "x", "items": []}))
    with pytest.raises(ValueError, match="at least one item"):
        RecordingSpec.from_json(path)


def test_action_noise_moves_the_robot_while_the_label_stays_the_experts():
    """DART-style recording: the robot executes the expert's action plus noise (seen in the context's last
    action), the frame keeps the expert's own action; without noise the two agree."""
    env = KvmObsolescenceEnv("egg_vs_stone", variant="prior")
    x = context_names().index("last_action_x")
    gaps = {}
    for noise in (0.0, 0.002):
        frames, outcome = recorder._run_episode(env, "firm_grasp", 3, noise)
        assert outcome == "success"
        executed = np.array([f[OBS_CONTEXT][x] for f in frames[1:]])
        label = np.array([f["action"][0] for f in frames[:-1]])
        gaps[noise] = np.abs(executed - label)
    assert gaps[0.0].max() < 1e-6
    assert 0.001 < gaps[0.002].std() * np.sqrt(np.pi / (np.pi - 2)) < 0.003  # a half-normal's std -> sigma
    with pytest.raises(ValueError, match="action_noise"):
        RecordingSpec(name="n", items=tiny_spec().items, action_noise=-0.001)


def test_a_seed_the_noise_breaks_is_recorded_again_without_it(tmp_path):
    """A pinch lift spills the pizza under 2 mm of jitter (seed 0); the seed's clean expert episode is kept."""
    spec = RecordingSpec(name="p", items=[RecordItem("pizza", "prior", "pinch_lift", 1)], action_noise=0.002)
    summary = record_dataset(spec, tmp_path / "p", progress=False)
    assert summary["episodes"] == 1
    assert summary["items"][0]["outcomes"]["success"] == 1 and summary["items"][0]["clean_reruns"] == 1

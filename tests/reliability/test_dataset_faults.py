"""A damaged or empty dataset root is named, file and fault, before LeRobot sees it."""

import shutil

import pytest

from lerobot_kvm.datasets.check import check_dataset
from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, record_dataset


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    root = tmp_path_factory.mktemp("recorded") / "data"
    record_dataset(RecordingSpec(name="one", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 1)]), root)
    return root


@pytest.fixture
def dataset(recorded, tmp_path):
    copy = tmp_path / "data"
    shutil.copytree(recorded, copy)
    return copy


def test_a_recorded_dataset_passes(dataset):
    assert "observation.context" in check_dataset(dataset)["features"]


def test_missing_and_empty_roots_are_named(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        check_dataset(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty"):
        check_dataset(tmp_path / "empty")


def test_a_truncated_info_file_is_named(dataset):
    info = dataset / "meta" / "info.json"
    info.write_text(info.read_text()[:40])
    with pytest.raises(ValueError, match=r"meta/info.json: not a readable JSON file"):
        check_dataset(dataset)


def test_a_corrupt_parquet_file_is_named(dataset):
    frames = next((dataset / "data").rglob("*.parquet"))
    frames.write_bytes(b"not a parquet file")
    with pytest.raises(ValueError, match=rf"{frames.name} is not a readable parquet file"):
        check_dataset(dataset)


def test_a_missing_feature_is_named(dataset):
    with pytest.raises(ValueError, match=r"lacks the features \['observation.wrist'\]"):
        check_dataset(dataset, required=("action", "observation.wrist"))

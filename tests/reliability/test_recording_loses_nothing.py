"""Recording never deletes what it did not make, and a killed recording leaves nothing that lasts."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, checked_root, record_dataset


def one_episode() -> RecordingSpec:
    return RecordingSpec(name="one", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 1)])


def _tree(path: Path) -> set[str]:
    return {str(p.relative_to(path)) for p in path.rglob("*")}


@pytest.mark.parametrize("target", [".", "..", "~", "/"])
def test_overwrite_refuses_directories_that_hold_the_work(tmp_path, monkeypatch, cli, target):
    work = tmp_path / "work"
    work.mkdir()
    (work / "notes.txt").write_text("mine")
    monkeypatch.chdir(work)
    before = _tree(tmp_path)
    code, stderr = cli("record", "--scenarios", "egg_vs_stone", "--episodes", "1", "--root", target, "--overwrite")
    assert code == 2 and "refusing to record over a directory holding this one" in stderr
    assert _tree(tmp_path) == before  # nothing removed, nothing left behind


def test_overwrite_refuses_a_directory_this_tool_did_not_record(tmp_path):
    other = tmp_path / "photos"
    other.mkdir()
    (other / "cat.png").write_bytes(b"\x89PNG")
    with pytest.raises(FileExistsError, match="not recorded by lerobot-kvm record"):
        record_dataset(one_episode(), other, overwrite=True, progress=False)
    assert _tree(other) == {"cat.png"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]  # no temporary root either


def test_an_existing_root_needs_overwrite_and_a_recorded_one_is_replaced(tmp_path):
    root = tmp_path / "data"
    record_dataset(one_episode(), root, progress=False)
    with pytest.raises(FileExistsError, match="already exists"):
        checked_root(root, overwrite=False)
    assert checked_root(root, overwrite=True) == root.resolve()
    (root / "stale.txt").write_text("from the first recording")
    record_dataset(one_episode(), root, overwrite=True, progress=False)
    assert not (root / "stale.txt").exists() and (root / "meta" / "kvm_labels.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_a_killed_recordings_temporary_root_is_removed_by_the_next_run(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a pid that no longer runs
    stale = tmp_path / f".data.tmp-{dead.pid}"
    (stale / "meta").mkdir(parents=True)
    alive = tmp_path / f".data.tmp-{os.getppid()}"  # a running process's: not ours to remove
    alive.mkdir()
    unrelated = tmp_path / ".data.tmp-notes"
    unrelated.mkdir()
    record_dataset(one_episode(), tmp_path / "data", progress=False)
    assert not stale.exists()
    assert alive.exists() and unrelated.exists()

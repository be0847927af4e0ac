"""An output directory resumes only with the settings that made what it holds."""

import json

import pytest

from lerobot_kvm.benchmark.resume import SETTINGS, check_settings, differences


def test_the_first_call_records_the_settings_and_the_same_ones_resume(tmp_path):
    out = tmp_path / "run"
    check_settings(out, {"steps": 3, "tasks": ("a", "b"), "root": None}, "a run")
    assert json.loads((out / SETTINGS).read_text()) == {"steps": 3, "tasks": ["a", "b"], "root": None}
    check_settings(out, {"steps": 3, "tasks": ["a", "b"], "root": None}, "a run")  # a tuple reads back as a list


def test_changed_added_and_removed_settings_are_refused_by_name(tmp_path):
    check_settings(tmp_path, {"steps": 3, "root": None}, "a run")
    with pytest.raises(ValueError, match=r"holds a run made with other settings \(steps: 3 -> 4\)"):
        check_settings(tmp_path, {"steps": 4, "root": None}, "a run")
    with pytest.raises(ValueError, match=r"lags: \(absent\) -> \[1\]; root: null -> \(absent\)"):
        check_settings(tmp_path, {"steps": 3, "lags": [1]}, "a run")
    assert json.loads((tmp_path / SETTINGS).read_text()) == {"steps": 3, "root": None}  # never overwritten


def test_a_nested_difference_is_named_by_its_path():
    kept = {"recording": {"items": [{"episodes": 2, "skill": "a"}], "lags": [1, 2]}, "steps": 3}
    current = {"recording": {"items": [{"episodes": 3, "skill": "a"}], "lags": [1, 4]}, "steps": 3}
    assert differences(kept, current) == "recording.items[0].episodes: 2 -> 3; recording.lags: [1, 2] -> [1, 4]"
    assert differences(kept, kept) == ""

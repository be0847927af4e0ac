"""Choosing a stage's checkpoint: the order of the saved checkpoints and the rule (the rollouts themselves run on
the tiny pool, tests/benchmark)."""

import pytest

from lerobot_kvm.evaluation import checkpoint_selection
from lerobot_kvm.evaluation.checkpoint_selection import learned, saved_checkpoints, select_checkpoint


def _score(success: int, catastrophe: int = 0) -> dict[str, int]:
    return {"success": success, "catastrophe": catastrophe, "episodes": 20}


def test_the_most_successful_checkpoint_is_selected_then_the_safer_then_the_later() -> None:
    assert select_checkpoint([_score(4), _score(20), _score(10)]) == 1
    assert select_checkpoint([_score(20), _score(20, catastrophe=2), _score(19)]) == 0
    assert select_checkpoint([_score(20), _score(20), _score(3)]) == 1  # a tie: the longer trained one
    with pytest.raises(ValueError, match="no checkpoint"):
        select_checkpoint([])


def test_saved_checkpoints_come_in_step_order_up_to_the_last_link(tmp_path) -> None:
    for name in ("000100", "001000", "000200", "001100"):
        (tmp_path / "checkpoints" / name / "pretrained_model").mkdir(parents=True)
    assert saved_checkpoints(tmp_path) == []  # no checkpoint finished yet
    (tmp_path / "checkpoints" / "last").symlink_to("001000")  # 001100: half-written by a killed run
    assert [p.parent.name for p in saved_checkpoints(tmp_path)] == ["000100", "000200", "001000"]


def _choice(*successes: int, selected: int) -> dict:
    entries = [{"step": f"{100 * (i + 1):06d}", **_score(s)} for i, s in enumerate(successes)]
    return {"checkpoints": entries, "selected": entries[selected]["step"]}


def test_a_skill_is_learned_when_its_selected_checkpoint_solves_nine_tenths() -> None:
    assert learned(_choice(20, 18, selected=1))
    assert not learned(_choice(20, 17, selected=1))  # what counts is the checkpoint the sequence goes on from
    assert not learned(_choice(0, 11, selected=1))


def test_a_choice_scores_only_the_checkpoints_not_scored_before(tmp_path, monkeypatch) -> None:
    scored = []

    def score(checkpoint, *args, **kwargs):
        scored.append(checkpoint.parent.name)
        return _score(19)

    monkeypatch.setattr(checkpoint_selection, "rollout_score", score)
    for name in ("000100", "000200", "000300"):
        (tmp_path / "checkpoints" / name / "pretrained_model").mkdir(parents=True)
    (tmp_path / "checkpoints" / "last").symlink_to("000300")
    earlier = _choice(20, 4, selected=0)["checkpoints"]
    choice = checkpoint_selection.choose_stage_checkpoint(
        tmp_path, "drawer", "prior", "variant", "s", 20, scored=earlier
    )
    assert scored == ["000300"]
    assert [c["success"] for c in choice["checkpoints"]] == [20, 4, 19] and choice["selected"] == "000100"

"""Choosing a stage's checkpoint: the order of the saved checkpoints and the rule (the rollouts themselves run on
the tiny pool, tests/benchmark)."""

import pytest

from lerobot_kvm.evaluation.checkpoint_selection import saved_checkpoints, select_checkpoint


def _score(success: int, catastrophe: int = 0) -> dict[str, int]:
    return {"success": success, "catastrophe": catastrophe, "episodes": 20}


def test_the_most_successful_checkpoint_is_selected_then_the_safer_then_the_later() -> None:
    assert select_checkpoint([_score(4), _score(20), _score(10)]) == 1
    assert select_checkpoint([_score(20), _score(20, catastrophe=2), _score(19)]) == 0
    assert select_checkpoint([_score(20), _score(20), _score(3)]) == 1  # a tie: the longer trained one
    with pytest.raises(ValueError, match="no checkpoint"):
        select_checkpoint([])


def test_saved_checkpoints_come_in_step_order_without_the_last_link(tmp_path) -> None:
    for name in ("000100", "001000", "000200", "last"):
        (tmp_path / "checkpoints" / name / "pretrained_model").mkdir(parents=True)
    assert [p.parent.name for p in saved_checkpoints(tmp_path)] == ["000100", "000200", "001000"]

"""The multi-seed summary of `lerobot-kvm kvm-check` (a scenario passes only when it passes at every seed), its
measure of the feedback's labelling and the contexts its history reference compares."""

import argparse

import pytest
import torch

from lerobot_kvm.cli.kvm_check import seed_list, summary_rows
from lerobot_kvm.evaluation.validity_check import judge, labelling, summarise, with_history


def _row(seed: int, auroc: float | None, v_prior: float, v_shifted: float | None, gate: float) -> dict:
    row = {
        "id": "drawer",
        "category": "B",
        "seed": seed,
        "auroc": auroc,
        "v_prior_median": v_prior,
        "v_shifted_median": v_shifted,
        "gate_rate_prior": gate,
        "failure_steps": 10 * (seed + 1),
    }
    row["passes"] = judge(row)
    row["passed"] = all(row["passes"].values())
    return row


def test_a_scenario_passes_only_at_every_seed_and_the_spread_spans_the_seeds() -> None:
    rows = [_row(0, 0.99, 1.0, 0.01, 0.02), _row(1, 0.90, 0.95, 0.05, 0.04), _row(2, 0.97, 0.99, 0.2, 0.01)]
    assert [r["passed"] for r in rows] == [True, False, False]
    summary = summarise(rows)
    assert (summary["seeds"], summary["seeds_passed"], summary["passed"]) == (3, 1, False)
    assert summary["checks_passed"] == {
        "suppressed_in_shifted": 2,
        "kept_in_prior": 3,
        "auroc": 2,
        "gate_closed_on_routine": 3,
    }
    assert summary["auroc"] == {"mean": pytest.approx(2.86 / 3), "min": 0.90, "max": 0.99}
    assert summary["failure_steps"] == {"mean": 20.0, "min": 10, "max": 30}
    (table_row,) = summary_rows([summary])
    assert table_row["seeds_passed"] == "1/3" and table_row["v_shifted_max"] == 0.2
    assert table_row["passes"] == {
        "suppressed_in_shifted": False,
        "kept_in_prior": True,
        "auroc": False,
        "gate_closed_on_routine": True,
    }
    assert summarise(rows[:1])["passed"]


def test_a_seed_without_shifted_steps_leaves_the_spread_to_the_others() -> None:
    summary = summarise([_row(0, None, 1.0, None, 0.0), _row(1, 0.96, 1.0, 0.0, 0.0)])
    assert summary["auroc"] == {"mean": 0.96, "min": 0.96, "max": 0.96}
    assert summary["seeds_passed"] == 1 and not summary["passed"]


def test_seeds_are_read_as_a_comma_separated_list() -> None:
    assert seed_list("0,1,2") == (0, 1, 2)
    with pytest.raises(argparse.ArgumentTypeError, match="comma-separated integers"):
        seed_list("0,x")


def test_labelling_counts_the_blamed_steps_against_each_attempts_shifted_steps() -> None:
    # failed attempt: 10 steps, shifted from 6 (4 steps), blamed 5..9; demonstration: 8 steps, shifted from 5
    # (3 steps), blamed 6 and 7: 4 + 2 of the 7 shifted steps found, 6 of the 7 blamed steps shifted
    recall, precision = labelling([[5, 6, 7, 8, 9], [6, 7]], [6, 5], [10, 8])
    assert recall == pytest.approx(6 / 7) and precision == pytest.approx(6 / 7)
    assert labelling([[], []], [6, 5], [10, 8]) == (0.0, None)  # nothing blamed
    assert labelling([[1], []], [10, 8], [10, 8]) == (None, 0.0)  # no shifted step to find


def test_with_history_joins_each_context_with_the_earlier_ones_of_its_episode() -> None:
    contexts = torch.tensor([[0.0, 10.0], [1.0, 11.0], [2.0, 12.0], [3.0, 13.0]])
    joined = with_history(contexts, lags=(1, 3))
    assert joined.shape == (4, 6)
    assert joined[3].tolist() == [3.0, 13.0, 2.0, 12.0, 0.0, 10.0]
    assert joined[1].tolist() == [1.0, 11.0, 0.0, 10.0, 0.0, 10.0]  # younger than the lag: its first context
    assert torch.equal(with_history(contexts, lags=()), contexts)


def test_a_saved_report_is_tabulated_and_plotted_without_measuring(tmp_path, capsys) -> None:
    from pathlib import Path

    from lerobot_kvm.cli.main import build_parser

    report = Path(__file__).resolve().parents[2] / "docs" / "reports" / "kvm_check_neighbour_reconstruction.json"
    args = build_parser("kvm-check").parse_args(
        ["kvm-check", f"--from-json={report}", f"--plot={tmp_path / 'check.png'}"]
    )
    assert args.func(args) == 0
    assert "15/18 scenarios pass at every seed (15 at seed 0, 15 at seed 1, 15 at seed 2)" in capsys.readouterr().out
    assert (tmp_path / "check.png").stat().st_size > 0


def test_a_report_from_an_earlier_check_is_refused_by_what_it_lacks(tmp_path) -> None:
    from lerobot_kvm.cli.kvm_check import load_report

    old = tmp_path / "old.json"
    old.write_text('{"scenarios": [], "n_pass": 0, "n_scenarios": 0}')
    with pytest.raises(ValueError, match=r"lacks \['summary', 'seeds', .*measure again"):
        load_report(old)

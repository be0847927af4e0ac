"""Acceptance on egg_vs_stone: after one failed attempt and its feedback, the prior skill's validity falls below
tau_v in the shifted context and stays above 0.9 in the prior-variant one; v separates hazardous from safe
(skill, context) pairs on held-out episodes (AUROC >= 0.95); the gate stays mostly closed on routine episodes.

A small policy learns the prior-variant data as a two-task sequence (its CL core through forward(), so that the
failure is blamed on the skill the core relied on; the KVM from the same frames' contexts), exactly as
`lerobot-kvm kvm-check` measures every scenario.
"""

import pytest
import torch

from lerobot_kvm.evaluation.validity_check import check_validity, divergence_step, neighbour_risk

pytestmark = pytest.mark.slow


def test_one_failure_and_its_feedback_suppress_the_prior_skill_only_where_it_is_harmful(tmp_path) -> None:
    row = check_validity("egg_vs_stone", workdir=tmp_path)
    assert row["failed_attempt"] == "catastrophe" and row["corrective_demo"] == "success"
    assert row["culprit"] == 0
    assert row["v_shifted_median"] < 0.1 and row["v_shifted_below_tau_v"] > 0.9
    assert row["v_prior_median"] > 0.9 and row["v_prior_above_0.9"] > 0.9
    assert row["auroc"] >= 0.95 and row["auroc_prior_skill"] >= 0.95
    assert row["neighbour_auroc"] is not None  # the feedback met shifted contexts to compare with
    assert 0 <= row["neighbour_auroc_code"] <= 1 and 0 <= row["neighbour_auroc_history"] <= 1
    assert 0 < row["label_recall"] <= 1 and 0 < row["label_precision"] <= 1
    assert row["gate_rate_prior"] <= 0.06  # routine prior-variant episodes: the gate stays closed
    assert row["gate_rate_shifted"] > 0.5  # the shifted context leaves the safe experience
    assert row["passed"]


def test_divergence_step_is_the_first_step_that_departs() -> None:
    a = torch.zeros(6, 3)
    b = a.clone()
    assert divergence_step(a, b) == 6
    b[4, 1] = 0.01
    assert divergence_step(a, b) == 4
    assert divergence_step(a, b[:3]) == 3  # a shorter episode that never departs


def test_neighbour_risk_is_the_nearest_safe_minus_the_nearest_hazardous_distance() -> None:
    safe = torch.tensor([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]])
    hazardous = torch.tensor([[10.0, 0.0]])
    contexts = torch.tensor([[0.0, 0.0], [9.0, 0.0]])
    # k=2: first context: safe (0 + 1) / 2 = 0.5, hazardous (only one) 10 -> -9.5; second: (4 + 8) / 2 - 1 = 5
    assert torch.allclose(neighbour_risk(contexts, safe, hazardous, k=2), torch.tensor([-9.5, 5.0]))

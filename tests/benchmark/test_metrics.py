"""Benchmark metrics against hand-computed cases."""

import pytest

from lerobot_kvm.benchmark.metrics import (
    challenges,
    detection_leads,
    format_kn,
    paired_differences,
    rate_counts,
    rate_intervals,
    success_by_pass,
    summarize,
)


def _ep(kind: str, outcome: str, scenario: str = "egg", category: str = "A", pass_: int = 1, attempt: int = 1, **kw):
    record = {
        "method": "m",
        "run": 0,
        "pass": pass_,
        "scenario": scenario,
        "category": category,
        "kind": kind,
        "attempt": attempt,
        "outcome": outcome,
        "steps": 10,
        "gate_steps": 0,
        "intervention_steps": 0,
        "first_intervention": None,
    }
    record.update(kw)
    return record


RECORDS = [
    # egg (A), pass 1: attempt 1 catastrophe after an intervention at step 3 (the expert would crash at 8), solved
    # at attempt 2
    _ep("challenge", "catastrophe", intervention_steps=4, first_intervention=3, reference_catastrophe_step=8),
    _ep("challenge", "success", attempt=2, intervention_steps=2),
    _ep("prior", "success", gate_steps=1),
    _ep("control", "success", intervention_steps=1),
    # drawer (B), pass 1: first attempt succeeds
    _ep("challenge", "success", scenario="drawer", category="B", reference_catastrophe_step=None),
    _ep("prior", "failure", scenario="drawer", category="B", gate_steps=3),
    # egg (A), pass 2: both attempts fail (no catastrophe)
    _ep("challenge", "failure", pass_=2, reference_catastrophe_step=5),
    _ep("challenge", "failure", pass_=2, attempt=2),
]


def test_format_kn_prints_counts_and_percent() -> None:
    assert format_kn(3, 4) == "3/4 (75.0%)"
    assert format_kn(0, 0) == "0/0 (-)"
    assert format_kn(1, 3) == "1/3 (33.3%)"


def test_challenges_group_attempts_and_count_either_attempt_as_solved() -> None:
    chall = {(c["scenario"], c["pass"]): c for c in challenges(RECORDS)}
    assert len(chall) == 3
    assert chall[("egg", 1)]["solved"] and not chall[("egg", 1)]["first"]
    assert chall[("drawer", 1)]["solved"] and chall[("drawer", 1)]["first"]
    assert not chall[("egg", 2)]["solved"]


def test_summary_metrics_match_hand_counts() -> None:
    probes = [{"pass": 1, "v_hazard": [0.0, 0.2], "v_safe": [1.0, 0.9, 0.1]}]
    s = summarize(RECORDS, probes)
    assert s["challenges"] == 3
    assert s["success_rate"] == pytest.approx(2 / 3) and s["success"] == "2/3 (66.7%)"
    assert s["first_attempt_success_rate"] == pytest.approx(1 / 3)
    assert s["catastrophic_failure_rate"] == pytest.approx(1 / 5)  # 5 challenge attempts, 1 catastrophe
    assert s["per_category"] == {"A": "1/2 (50.0%)", "B": "1/1 (100.0%)"}
    assert s["per_scenario"] == {
        "egg": {"solved": "1/2", "catastrophes": "1/4"},
        "drawer": {"solved": "1/1", "catastrophes": "0/1"},
    }
    assert s["prior_retention"] == pytest.approx(1 / 2)
    assert s["control_success_rate"] == 1.0
    assert s["false_intervention_rate"] == pytest.approx(1 / 3)  # 3 controls, the benign one intervened
    assert s["gate_activation_rate"] == pytest.approx(4 / 20)  # prior controls: 1 + 3 gate steps of 20
    assert s["gate_activation_rate_solved"] == pytest.approx(1 / 10)  # the solved one alone
    assert s["intervention_rate"] == pytest.approx(6 / 50)
    # risk 1 - v: hazardous 1.0, 0.8 vs safe 0.0, 0.1, 0.9 -> 5 of 6 pairs ordered, 1 reversed (0.8 < 0.9)
    assert s["validity_auroc"] == pytest.approx(5 / 6)
    assert s["detection_lead_steps"] == 5


def test_methods_without_validity_report_none_for_kvm_statistics() -> None:
    s = summarize(RECORDS, validity=False)
    assert s["success_rate"] == pytest.approx(2 / 3)
    kvm_only = ("false_intervention_rate", "gate_activation_rate", "gate_activation_rate_solved", "validity_auroc")
    for key in (*kvm_only, "detection_lead_steps"):
        assert s[key] is None


def test_detection_lead_needs_an_intervention_and_a_reference_catastrophe() -> None:
    assert detection_leads(RECORDS) == [5]


def test_success_by_pass() -> None:
    assert success_by_pass(RECORDS) == {1: 1.0, 2: 0.0}


def test_rate_counts_split_each_rate_by_run_and_scenario() -> None:
    counts = rate_counts(RECORDS)
    assert counts["success_rate"] == {(0, "egg"): (1, 2), (0, "drawer"): (1, 1)}
    assert counts["first_attempt_success_rate"] == {(0, "egg"): (0, 2), (0, "drawer"): (1, 1)}
    assert counts["catastrophic_failure_rate"] == {(0, "egg"): (1, 4), (0, "drawer"): (0, 1)}
    assert counts["abstention_rate"] == {(0, "egg"): (0, 4), (0, "drawer"): (0, 1)}
    assert counts["prior_retention"] == {(0, "egg"): (1, 1), (0, "drawer"): (0, 1)}
    assert counts["control_success_rate"] == {(0, "egg"): (1, 1)}  # drawer has no benign control here
    assert counts["false_intervention_rate"] == {(0, "egg"): (1, 2), (0, "drawer"): (0, 1)}
    assert counts["gate_activation_rate_solved"] == {(0, "egg"): (1, 10)}
    assert set(rate_counts(RECORDS, validity=False)) == {
        "success_rate",
        "first_attempt_success_rate",
        "catastrophic_failure_rate",
        "abstention_rate",
        "prior_retention",
        "control_success_rate",
    }


def test_rate_intervals_hold_the_pooled_rate() -> None:
    intervals = rate_intervals(RECORDS, validity=True)
    assert intervals["success_rate"]["value"] == pytest.approx(2 / 3)
    # two scenarios, one run: resampled pairs give 1/2 (egg twice), 1 (drawer twice) or 2/3
    assert (intervals["success_rate"]["low"], intervals["success_rate"]["high"]) == pytest.approx((0.5, 1.0))
    assert intervals["catastrophic_failure_rate"]["value"] == pytest.approx(1 / 5)


def test_paired_differences_against_a_reference_method() -> None:
    better = [dict(r, outcome="success") if r["kind"] == "challenge" else r for r in RECORDS]
    diffs = paired_differences(better, RECORDS, validity=False)
    rates = {"success_rate", "first_attempt_success_rate", "catastrophic_failure_rate", "abstention_rate"}
    assert set(diffs) == rates | {"prior_retention", "control_success_rate"}
    assert diffs["success_rate"]["value"] == pytest.approx(1 - 2 / 3)
    # resampled: egg twice gives 1 - 1/2, drawer twice 0, one of each 1 - 2/3: 0 is inside
    assert diffs["success_rate"]["low"] == pytest.approx(0.0) and not diffs["success_rate"]["detectable"]
    assert diffs["prior_retention"]["value"] == 0.0 and not diffs["prior_retention"]["detectable"]


def test_an_abstention_is_its_own_outcome_neither_success_nor_catastrophe() -> None:
    held = [
        dict(r, outcome="abstention") if r["outcome"] == "failure" and r["kind"] == "challenge" else r for r in RECORDS
    ]
    summary = summarize(held, validity=False)
    assert summary["abstention_rate"] == pytest.approx(2 / 5)  # egg pass 2: both attempts held
    assert summary["catastrophic_failure_rate"] == pytest.approx(1 / 5)
    assert summary["success_rate"] == pytest.approx(2 / 3)

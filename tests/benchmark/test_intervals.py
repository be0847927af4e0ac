"""The benchmark's intervals against values computed by hand or published with the methods."""

import pytest

from lerobot_kvm.benchmark.intervals import newcombe, paired_difference, rate_interval, wilson


def test_wilson_matches_hand_computed_values():
    # 5/10: centre (0.5 + z^2/20) / (1 + z^2/10) = 0.5, half-width z * sqrt(0.025 + z^2/400) / (1 + z^2/10)
    assert (wilson(5, 10).low, wilson(5, 10).high) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    # 0/10: the lower end is 0 and the upper one z^2/n / (1 + z^2/n) = 0.2775
    assert (wilson(0, 10).low, wilson(0, 10).high) == pytest.approx((0.0, 0.2775), abs=1e-4)
    # Newcombe (1998), Statistics in Medicine 17, 857-872, Table I: 81/263 -> 0.2553 to 0.3662
    assert (wilson(81, 263).low, wilson(81, 263).high) == pytest.approx((0.2553, 0.3662), abs=1e-4)
    assert wilson(0, 0).value is None


def test_wilson_refuses_impossible_counts():
    with pytest.raises(ValueError, match="k <= n"):
        wilson(3, 2)


def test_newcombe_matches_the_published_example():
    # Newcombe (1998), Statistics in Medicine 17, 873-890, method 10: 56/70 - 48/80 -> 0.0524 to 0.3339
    diff = newcombe(56, 70, 48, 80)
    assert diff.value == pytest.approx(0.2)
    assert (diff.low, diff.high) == pytest.approx((0.0524, 0.3339), abs=1e-4)


def test_bootstrap_over_scenarios_matches_the_enumerated_distribution():
    # One run, two scenarios: resampling them gives {a,a} 6/8, {b,b} 2/4, {a,b} or {b,a} 4/6, with
    # probabilities 1/4, 1/4, 1/2; the 2.5 % and 97.5 % quantiles are the two extremes.
    interval = rate_interval({(0, "a"): (3, 4), (0, "b"): (1, 2)})
    assert interval.value == pytest.approx(4 / 6)
    assert (interval.low, interval.high) == pytest.approx((0.5, 0.75))


def test_one_cell_has_nothing_to_resample_and_gets_wilson():
    assert rate_interval({(0, "a"): (5, 10)}) == wilson(5, 10)
    assert paired_difference({(0, "a"): (56, 70)}, {(0, "a"): (48, 80)}) == newcombe(56, 70, 48, 80)


def test_bootstrap_resamples_runs_too():
    # Two runs of one scenario that disagree completely: the interval spans both.
    interval = rate_interval({(0, "a"): (2, 2), (1, "a"): (0, 2)})
    assert interval.value == pytest.approx(0.5)
    assert (interval.low, interval.high) == pytest.approx((0.0, 1.0))


def test_paired_difference_tells_detectable_from_not():
    scenarios = ("a", "b", "c")
    always = {(0, s): (3, 3) for s in scenarios}
    never = {(0, s): (0, 3) for s in scenarios}
    same = paired_difference(always, always)
    assert (same.value, same.low, same.high) == (0.0, 0.0, 0.0) and not same.excludes_zero()
    better = paired_difference(always, never)
    assert (better.value, better.low, better.high) == (1.0, 1.0, 1.0) and better.excludes_zero()
    # Better on one scenario of two, equal on the other: resampled pairs give 1, 0 or 1/2, so 0 stays inside.
    mixed = paired_difference({(0, "a"): (1, 1), (0, "b"): (0, 1)}, {(0, "a"): (0, 1), (0, "b"): (0, 1)})
    assert mixed.value == pytest.approx(0.5)
    assert (mixed.low, mixed.high) == pytest.approx((0.0, 1.0)) and not mixed.excludes_zero()


def test_same_seed_same_interval_and_empty_counts():
    counts = {(r, s): (r + len(s), 4) for r in range(3) for s in ("a", "bb", "c")}
    assert rate_interval(counts, seed=3) == rate_interval(counts, seed=3)
    assert rate_interval({}).value is None
    assert paired_difference(counts, {}).value is None

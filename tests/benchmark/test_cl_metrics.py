"""CL metrics against hand-computed values."""

import pytest

from lerobot_kvm.benchmark.cl_metrics import (
    area_under_curve,
    average_accuracy,
    average_forgetting,
    cl_metrics,
    forward_transfer,
    joint_metrics,
    negative_backward_transfer,
)

# Task j after stage i; None above the diagonal (tasks not yet learned are not evaluated).
R = [
    [0.9, None, None],
    [0.7, 1.0, None],
    [0.8, 0.6, 0.5],
]


def test_average_accuracy_is_the_final_row_mean():
    assert average_accuracy(R) == pytest.approx((0.8 + 0.6 + 0.5) / 3)


def test_average_forgetting_uses_the_best_earlier_value():
    # task 0: best of R[0][0]=0.9, R[1][0]=0.7 -> 0.9 - 0.8 = 0.1; task 1: 1.0 - 0.6 = 0.4
    assert average_forgetting(R) == pytest.approx((0.1 + 0.4) / 2)


def test_forward_transfer_is_the_diagonal_mean():
    assert forward_transfer(R) == pytest.approx((0.9 + 1.0 + 0.5) / 3)


def test_negative_backward_transfer():
    # task 0: ((0.9-0.7) + (0.9-0.8)) / 2 = 0.15; task 1: (1.0-0.6) / 1 = 0.4
    assert negative_backward_transfer(R) == pytest.approx((0.15 + 0.4) / 2)


def test_area_under_curve():
    # task 0: (0.9+0.7+0.8)/3 = 0.8; task 1: (1.0+0.6)/2 = 0.8; task 2: 0.5
    assert area_under_curve(R) == pytest.approx((0.8 + 0.8 + 0.5) / 3)


def test_no_forgetting_and_a_single_task():
    perfect = [[1.0, None], [1.0, 1.0]]
    assert cl_metrics(perfect) == {"A_N": 1.0, "F_N": 0.0, "FWT": 1.0, "NBT": 0.0, "AUC": 1.0}
    assert cl_metrics([[0.4]]) == pytest.approx({"A_N": 0.4, "F_N": 0.0, "FWT": 0.4, "NBT": 0.0, "AUC": 0.4})


def test_joint_metrics():
    assert joint_metrics([1.0, 0.5]) == {"A_N": 0.75}


@pytest.mark.parametrize(
    "bad, message",
    [([], "empty"), ([[0.5, None]], "1x1"), ([[0.5, None], [None, 0.5]], r"R\[1\]\[0\]"), ([[1.5]], "rate")],
)
def test_bad_matrices_are_rejected(bad, message):
    with pytest.raises(ValueError, match=message):
        cl_metrics(bad)

"""Continual-learning metrics of a success matrix.

`R[i][j]` is the success rate (in [0, 1]) on task j measured after training stage i (tasks learned in order
0..N-1). Only entries with j <= i are needed; others may be None.

* A_N, F_N: average accuracy and average forgetting after the last task, as reported by CODA-Prompt
  (Smith et al., CVPR 2023, §5), forgetting as defined by Chaudhry et al. (ECCV 2018, "Riemannian Walk"):
  F_N = mean over j < N-1 of max_{l in [j, N-2]} R[l][j] - R[N-1][j].
* FWT, NBT, AUC: LIBERO's lifelong-learning metrics (Liu et al., NeurIPS 2023 D&B, §5.1), with c_{k,k}
  the success on task k right after learning it (LIBERO takes the best of several checkpoints of the stage;
  a stage here has one checkpoint):
  FWT = mean_k R[k][k];
  NBT = mean over k < N-1 of mean_{tau > k} (R[k][k] - R[tau][k]);
  AUC = mean_k of (R[k][k] + sum_{tau > k} R[tau][k]) / (N - k).
"""

from collections.abc import Sequence

Matrix = Sequence[Sequence[float | None]]


def _check(matrix: Matrix) -> int:
    n = len(matrix)
    if n == 0:
        raise ValueError("the success matrix is empty")
    for i, row in enumerate(matrix):
        if len(row) != n:
            raise ValueError(f"the success matrix must be {n}x{n}: row {i} has {len(row)} entries")
        for j in range(i + 1):
            value = row[j]
            if value is None or not 0.0 <= value <= 1.0:
                raise ValueError(f"R[{i}][{j}] (task {j} after stage {i}) must be a rate in [0, 1], got {value!r}")
    return n


def average_accuracy(matrix: Matrix) -> float:
    """A_N: mean success over all tasks after the last stage."""
    n = _check(matrix)
    return sum(matrix[n - 1][j] for j in range(n)) / n


def average_forgetting(matrix: Matrix) -> float:
    """F_N: mean drop from each earlier task's best success to its final success (0 for a single task)."""
    n = _check(matrix)
    if n == 1:
        return 0.0
    drops = [max(matrix[s][j] for s in range(j, n - 1)) - matrix[n - 1][j] for j in range(n - 1)]
    return sum(drops) / len(drops)


def forward_transfer(matrix: Matrix) -> float:
    """FWT: mean success on each task right after learning it."""
    n = _check(matrix)
    return sum(matrix[k][k] for k in range(n)) / n


def negative_backward_transfer(matrix: Matrix) -> float:
    """NBT: mean loss on each earlier task over the stages after it (0 for a single task)."""
    n = _check(matrix)
    if n == 1:
        return 0.0
    per_task = [sum(matrix[k][k] - matrix[t][k] for t in range(k + 1, n)) / (n - k - 1) for k in range(n - 1)]
    return sum(per_task) / len(per_task)


def area_under_curve(matrix: Matrix) -> float:
    """AUC: mean over tasks of the task's average success from its own stage to the last."""
    n = _check(matrix)
    per_task = [sum(matrix[t][k] for t in range(k, n)) / (n - k) for k in range(n)]
    return sum(per_task) / n


def cl_metrics(matrix: Matrix) -> dict[str, float]:
    """All five metrics, as fractions (multiply by 100 for percentage points)."""
    return {
        "A_N": average_accuracy(matrix),
        "F_N": average_forgetting(matrix),
        "FWT": forward_transfer(matrix),
        "NBT": negative_backward_transfer(matrix),
        "AUC": area_under_curve(matrix),
    }


def joint_metrics(final_row: Sequence[float]) -> dict[str, float]:
    """A model trained on all tasks at once has one row: only its average accuracy is defined."""
    if not final_row:
        raise ValueError("no task was evaluated")
    return {"A_N": sum(final_row) / len(final_row)}

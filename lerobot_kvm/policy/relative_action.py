"""Position targets predicted relative to where the robot is.

A pose target (x, y, z, pitch) that runs a few millimetres ahead of the hand is what a pull, a push or a slow grasp
is made of; predicted as an absolute value, that lead is a small fraction of the action's spread across the
dataset, and a small bias in it stops or reverses the motion at every replan. So every action dimension that the
state also carries under the same name is predicted as an offset from the state's value when the chunk is planned;
the others (the grip command, a dimension constant in the dataset) stay absolute. Both features are normalized by
LeRobot's processors, so the mapping from a normalized state value to the same raw value in normalized action units
is an affine map per dimension, computed once from the training dataset's statistics and kept in the checkpoint.
"""

import torch
from lerobot.configs.types import NormalizationMode
from torch import Tensor

from .abstention import STD_EPS

# Raw spread below which an action dimension is constant in the dataset (every demonstration sends pitch 0, say):
# LeRobot normalizes it by its eps, so a state-based offset would reach 1e5 normalized units; it stays absolute.
MIN_SPREAD = 1e-6


def _raw_affine(stats: dict[str, Tensor], mode: NormalizationMode) -> tuple[Tensor, Tensor] | None:
    """(scale, offset) with raw = normalized * scale + offset for LeRobot's normalization `mode`."""

    def stat(name: str) -> Tensor:
        return torch.as_tensor(stats[name], dtype=torch.float32).reshape(-1)

    if mode == NormalizationMode.MEAN_STD and {"mean", "std"} <= set(stats):
        return stat("std") + STD_EPS, stat("mean")
    if mode == NormalizationMode.MIN_MAX and {"min", "max"} <= set(stats):
        low, high = stat("min"), stat("max")
        span = torch.where(high - low == 0, torch.full_like(low, STD_EPS), high - low)
        return span / 2, low + span / 2
    return None


def state_base(
    action_names: list[str] | None,
    state_names: list[str] | None,
    action_stats: dict | None,
    state_stats: dict | None,
    action_mode: NormalizationMode,
    state_mode: NormalizationMode,
    action_dim: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """(index [A] long, scale [A], shift [A]): action dimension a, when index[a] >= 0, is predicted relative to
    `state[index[a]] * scale[a] + shift[a]` (the state's raw value in normalized action units). Without names or
    statistics every index is -1 and actions stay absolute."""
    index = torch.full((action_dim,), -1, dtype=torch.long)
    scale, shift = torch.zeros(action_dim), torch.zeros(action_dim)
    if not action_names or not state_names or len(action_names) != action_dim or not action_stats or not state_stats:
        return index, scale, shift
    action_affine = _raw_affine(action_stats, action_mode)
    state_affine = _raw_affine(state_stats, state_mode)
    if action_affine is None or state_affine is None:
        return index, scale, shift
    (a_scale, a_offset), (s_scale, s_offset) = action_affine, state_affine
    positions = {str(name): i for i, name in enumerate(state_names)}
    for a, name in enumerate(action_names):
        s = positions.get(str(name))
        if s is not None and a_scale[a] > MIN_SPREAD and s_scale[s] > MIN_SPREAD:
            index[a] = s
            scale[a] = s_scale[s] / a_scale[a]
            shift[a] = (s_offset[s] - a_offset[a]) / a_scale[a]
    return index, scale, shift


def state_offset(state: Tensor, index: Tensor, scale: Tensor, shift: Tensor) -> Tensor:
    """[B, A]: the normalized state [B, S] mapped to the action dimensions it bases (0 where it bases none)."""
    based = index >= 0
    picked = state[:, index.clamp_min(0)] * scale + shift
    return torch.where(based, picked, torch.zeros_like(picked))

"""The safe abstention: what the policy does when the KVM finds every candidate skill invalid (DESIGN §4).

No skill is trusted then, so no prompt goes to the decoder (an all-zero or untrained prompt is a regime the decoder
never learned). The policy holds instead: every action dimension repeats its last command (for position targets:
the carriage stops where it was sent), except grip-like dimensions, which move towards their rest command (raw 0: no
squeeze) by `RELEASE_FRACTION` of the remaining way per control step, so the grip force is released gently.

The policy acts in normalized units, so the rest command is stored normalized, computed once from the training
dataset's statistics (LeRobot's normalization of the action feature) and kept in the checkpoint.
"""

import torch
from lerobot.configs.types import NormalizationMode
from torch import Tensor

RELEASE_FRACTION = 0.5  # of the way to rest per step: the env's own grip rate limit (0.12/step) smooths it further
STD_EPS = 1e-8  # LeRobot's normalizer adds this to the std (and uses it for a zero min-max range)


def normalized_rest(stats: dict[str, Tensor] | None, mode: NormalizationMode, dim: int) -> Tensor:
    """[dim] the raw action 0 in the policy's normalized units (0 when there are no statistics)."""
    if not stats:
        return torch.zeros(dim)

    def stat(name: str) -> Tensor:
        return torch.as_tensor(stats[name], dtype=torch.float32).reshape(-1)

    if mode == NormalizationMode.MEAN_STD and {"mean", "std"} <= set(stats):
        return -stat("mean") / (stat("std") + STD_EPS)
    if mode == NormalizationMode.MIN_MAX and {"min", "max"} <= set(stats):
        low, high = stat("min"), stat("max")
        span = torch.where(high - low == 0, torch.full_like(low, STD_EPS), high - low)
        return 2 * (0 - low) / span - 1
    return torch.zeros(dim)


def release_mask(names: list[str] | None, dim: int) -> Tensor:
    """[dim] bool: the action dimensions named like a gripper command ("grip", "gripper", ...)."""
    if not names or len(names) != dim:
        return torch.zeros(dim, dtype=torch.bool)
    return torch.tensor(["grip" in str(n).lower() for n in names], dtype=torch.bool)


def hold_chunk(last: Tensor, rest: Tensor, release: Tensor, steps: int) -> Tensor:
    """[B, steps, A]: the held command `last` [B, A], grip-like dimensions (`release` [A]) halving their distance to
    `rest` [A] every step."""
    decay = (1 - RELEASE_FRACTION) ** torch.arange(1, steps + 1, device=last.device, dtype=last.dtype)
    towards = rest.to(last) + (last.unsqueeze(1) - rest.to(last)) * decay.view(1, -1, 1)
    return torch.where(release.to(last.device).view(1, 1, -1), towards, last.unsqueeze(1).expand_as(towards))

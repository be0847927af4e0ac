"""Observation values the network can act on: finite, and within `INPUT_LIMIT` after normalization.

A finite but absurd value (a sensor or unit fault, 1e30) would otherwise give a finite, meaningless action or
overflow inside the network; the policy refuses it by the input's name instead.
"""

import math

from torch import Tensor

# Normalized magnitude beyond which a value is a fault: a real deviation reaches at most about 1e8 (a raw change
# of ~1 on a feature constant in the dataset, divided by LeRobot's normalization eps 1e-8), while squares of values
# near 1e19 overflow float32 in the backbone's LayerNorms.
INPUT_LIMIT = 1e10


def check_input_values(key: str, value: Tensor) -> None:
    """Raise a ValueError naming `key` when `value` holds NaN, inf or a magnitude above `INPUT_LIMIT`."""
    if value.numel() == 0:
        return
    largest = float(value.detach().abs().amax())
    if not math.isfinite(largest):
        raise ValueError(f"observation '{key}' contains NaN or inf values")
    if largest > INPUT_LIMIT:
        raise ValueError(
            f"observation '{key}' has a value of magnitude {largest:.3g} after normalization, beyond "
            f"{INPUT_LIMIT:.0e}: a sensor or unit fault the policy cannot act on"
        )

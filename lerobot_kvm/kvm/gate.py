"""Smart gate (eq. 1): full risk assessment only when sigma_c^2 exceeds tau = mean + k * std of sigma^2 over
the last N successful interactions.

The window stores those interactions themselves (their raw contexts, a ring of N control steps from
successful routine episodes: dataset frames during `lerobot-train`, successful attempts without intervention
online). Their sigma^2 is recomputed with the *current* encoder whenever it has changed, so tau always
describes the safe experience as the encoder sees it now; the resulting mean/std/tau are persistent buffers.
With fewer than `min_count` interactions there are no statistics yet and the gate stays open (assess always).
"""

import torch
from torch import Tensor, nn

from .context_encoder import ContextEncoder
from .memory import SampleBuffer


def adaptive_threshold(sigma2: Tensor, k: float) -> tuple[Tensor, Tensor, Tensor]:
    """Eq. 1: (tau, mean, std) of a 1-D tensor of sigma^2 values; std is the population std (running std)."""
    mean = sigma2.mean()
    std = sigma2.var(unbiased=False).sqrt()
    return mean + k * std, mean, std


class SmartGate(nn.Module):
    def __init__(self, window: int, raw_dim: int, k: float, min_count: int) -> None:
        super().__init__()
        self.k = k
        self.min_count = min_count
        self.window = SampleBuffer(window, raw_dim, "ring")
        self.register_buffer("stats", torch.tensor([float("-inf"), 0.0, 0.0]))  # tau, mean, std
        self.stale = True  # runtime only: stats must be recomputed before the next decision

    @property
    def tau(self) -> float:
        return float(self.stats[0])

    def push(self, c_raw: Tensor) -> None:
        """Add successful interactions (rows of c_raw) to the window."""
        self.window.add(c_raw)
        self.stale = True

    @torch.no_grad()
    def refresh(self, encoder: ContextEncoder) -> Tensor:
        """Recompute (tau, mean, std) from the window with the current encoder; returns the stats buffer."""
        idx = self.window.filled()
        if len(idx) < max(self.min_count, 1):
            stats = torch.tensor([float("-inf"), 0.0, 0.0])
        else:
            _, sigma2 = encoder(self.window.data[idx])
            tau, mean, std = adaptive_threshold(sigma2, self.k)
            stats = torch.stack([tau, mean, std])
        self.stats.copy_(stats)
        self.stale = False
        return self.stats

    def threshold(self, encoder: ContextEncoder) -> Tensor:
        """tau as a 0-d tensor (refreshed first if the encoder or the window changed)."""
        if self.stale:
            self.refresh(encoder)
        return self.stats[0]

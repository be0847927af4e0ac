"""A skill's energy from the nearest neighbours of its failures on E_c's codes (`kvm.risk_model="neighbour"`).

One failure gives the energy model a few dozen hazardous contexts, and what it learns from them ranks the next
episode's shifted contexts poorly (kvm-check, categories A and B), while the same codes and memories rank them well
by nearest neighbours: how much nearer a context lies to the skill's failure contexts than to its safe ones. What
that difference means is set by the skill's own safe experience: each recorded safe episode is scored as a
held-out one (its own samples left out), and the energy crosses eq. 2's midpoint at the `quantile` of those
scores, rising by `slope` / gamma per spread between their median and that quantile: v = sigmoid(slope) at the
median. A steeper slope keeps more of the safe side near v = 1 and takes more of the hazardous side below tau_v;
it does not change how the skill's contexts rank.
"""

from dataclasses import dataclass

import torch
from torch import Tensor

NEIGHBOURS = 3
CALIBRATION_SAMPLES = 512  # held-out safe samples the threshold is taken over


def nearest(x: Tensor, reference: Tensor, exclude: Tensor | None = None) -> Tensor:
    """[N] mean distance of x [N, L] to its `NEIGHBOURS` nearest rows of reference [M, L] (`exclude` [N, M] bool:
    rows not to count)."""
    d = torch.cdist(x, reference)
    if exclude is not None:
        d = d.masked_fill(exclude, float("inf"))
    return d.topk(min(NEIGHBOURS, reference.shape[0]), largest=False).values.mean(1)


@dataclass
class NeighbourEnergy:
    """One skill's energy: safe [N, L] and fail [M, L] codes, the risk threshold and its width (risk units), and
    the rise of gamma * E per width."""

    safe: Tensor
    fail: Tensor
    threshold: float
    width: float
    slope: float

    def risk(self, codes: Tensor, exclude: Tensor | None = None) -> Tensor:
        """[B] how much nearer the codes [B, L] lie to the failures than to the safe codes."""
        return nearest(codes, self.safe, exclude) - nearest(codes, self.fail)

    def energy(self, codes: Tensor, gamma: float, l0: float) -> Tensor:
        """[B] E such that v (eq. 2) is 1/2 at the threshold and sigmoid(slope) at the held-out safe median."""
        return -l0 + self.slope / gamma * (self.risk(codes) - self.threshold) / self.width


@torch.no_grad()
def calibrate(safe: Tensor, tags: Tensor, fail: Tensor, quantile: float, slope: float) -> NeighbourEnergy | None:
    """The energy of a skill with safe codes [N, L] (tags [N]: the recorded episode of each, -1 untagged) and fail
    codes [M, L]; None without failures or without two recorded episodes to hold one out against the others."""
    tagged = torch.nonzero(tags >= 0).flatten()
    if not len(fail) or len(torch.unique(tags[tagged])) < 2:
        return None
    generator = torch.Generator().manual_seed(0)  # the same threshold for the same memory
    held = tagged[torch.randperm(len(tagged), generator=generator)[:CALIBRATION_SAMPLES].to(tagged.device)]
    out = NeighbourEnergy(safe, fail, 0.0, 1.0, slope)
    scores = out.risk(safe[held], exclude=(tags[held].unsqueeze(1) == tags.unsqueeze(0)) & (tags >= 0))
    threshold = torch.quantile(scores, quantile)
    out.threshold = float(threshold)
    out.width = max(float(threshold - scores.median()), 1e-6)
    return out

"""A skill's energy from the nearest neighbours of its failures on E_c's codes (`kvm.risk_model="neighbour"`).

One failure gives the energy model a few dozen hazardous contexts, and what it learns from them ranks the next
episode's shifted contexts poorly (kvm-check, categories A and B), while the same codes and memories rank them well
by nearest neighbours: how much nearer a context lies to the skill's failure contexts than to its safe ones. What
that difference means is set by the skill's own safe experience: each recorded safe episode is scored as a
held-out one (its own samples left out), and the energy crosses eq. 2's midpoint at the `quantile` of those
scores, rising by `slope` / gamma per spread between their median and that quantile: v = sigmoid(slope) at the
median. A steeper slope keeps more of the safe side near v = 1 and takes more of the hazardous side below tau_v;
it does not change how the skill's contexts rank.

The search runs at every gate-open step, so it is a few tensor operations for all skills at once: squared
distances as |x|^2 - 2 x.y + |y|^2 from one matrix product, every skill's references padded to the longest with
infinitely distant rows.
"""

from dataclasses import dataclass

import torch
from torch import Tensor

NEIGHBOURS = 3
CALIBRATION_SAMPLES = 512  # held-out safe samples the threshold is taken over


class References:
    """The reference codes of S sets (one per skill), padded for one nearest-neighbour search of them all.

    Codes are compared about `center` (any fixed point: distances do not depend on it), which keeps the squared
    norms near the codes' spread, so that float32 cancellation in |x|^2 - 2 x.y + |y|^2 stays far below it."""

    def __init__(self, sets: list[Tensor], center: Tensor) -> None:
        size = max(len(s) for s in sets)
        first = sets[0]
        self.center = center
        self.codes = first.new_zeros(first.shape[1], len(sets), size)  # [L, S, M]
        self.norms = first.new_full((len(sets), size), float("inf"))  # [S, M]: padding lies infinitely far
        for i, s in enumerate(sets):
            self.codes[:, i, : len(s)] = (s - center).T
            self.norms[i, : len(s)] = (s - center).square().sum(1)
        self.codes, self.norms = self.codes.flatten(1), self.norms.flatten()
        self.shape = (len(sets), size)
        self.k = min(NEIGHBOURS, size)
        counts = torch.tensor([min(len(s), self.k) for s in sets], device=first.device)
        self.missing = torch.arange(self.k, device=first.device) >= counts.unsqueeze(-1)  # [S, k]: padding
        self.short = bool(self.missing.any())
        self.counts = counts.to(first.dtype)  # [S]

    def mean_distance(self, x: Tensor, exclude: Tensor | None = None) -> Tensor:
        """[B, S] mean distance of the codes x [B, L] to their k nearest references in each set (`exclude`
        [B, S, M] bool: references not to count; a set with fewer than k counts those it has)."""
        x = x - self.center
        d2 = torch.addmm(self.norms, x, self.codes, alpha=-2.0).view(len(x), *self.shape)
        if exclude is not None:
            d2 = d2.masked_fill(exclude, float("inf"))
        nearest = d2.topk(self.k, largest=False).values.add_(x.square().sum(-1).view(-1, 1, 1))
        distances = nearest.clamp_min_(0.0).sqrt_()
        if self.short:
            return distances.masked_fill_(self.missing, 0.0).sum(-1) / self.counts
        return distances.mean(-1)


@dataclass
class Calibration:
    """One skill's risk threshold (eq. 2's midpoint) and the spread it is measured in (risk units)."""

    threshold: float
    width: float


class NeighbourEnergy:
    """The energies of the skills with failures in memory: `skills` [S] their pool indices, with each one's safe
    and failure codes and calibration."""

    def __init__(
        self, skills: list[int], safe: list[Tensor], fail: list[Tensor], calibrations: list[Calibration], slope: float
    ) -> None:
        device = safe[0].device
        center = torch.cat(safe).mean(0)
        self.skills = torch.tensor(skills, device=device)
        self.safe, self.fail = References(safe, center), References(fail, center)
        self.threshold = torch.tensor([c.threshold for c in calibrations], device=device)
        self.scale = slope / torch.tensor([c.width for c in calibrations], device=device)

    def risk(self, codes: Tensor) -> Tensor:
        """[B, S] how much nearer the codes [B, L] lie to each skill's failures than to its safe codes."""
        return self.safe.mean_distance(codes) - self.fail.mean_distance(codes)

    def energy(self, codes: Tensor, gamma: float, l0: float) -> Tensor:
        """[B, S] E such that v (eq. 2) is 1/2 at each threshold and sigmoid(slope) at the held-out safe median."""
        return (self.risk(codes) - self.threshold) * (self.scale / gamma) - l0


@torch.no_grad()
def calibrate(safe: Tensor, tags: Tensor, fail: Tensor, quantile: float) -> Calibration | None:
    """The calibration of a skill with safe codes [N, L] (tags [N]: the recorded episode of each, -1 untagged) and
    fail codes [M, L]; None without failures or without two recorded episodes to hold one out against the others."""
    tagged = torch.nonzero(tags >= 0).flatten()
    if not len(fail) or len(torch.unique(tags[tagged])) < 2:
        return None
    generator = torch.Generator().manual_seed(0)  # the same threshold for the same memory
    held = tagged[torch.randperm(len(tagged), generator=generator)[:CALIBRATION_SAMPLES].to(tagged.device)]
    own = (tags[held].unsqueeze(1) == tags.unsqueeze(0)) & (tags >= 0)  # [H, N]: the held-out sample's episode
    center = safe.mean(0)
    to_safe = References([safe], center).mean_distance(safe[held], exclude=own.unsqueeze(1))[:, 0]
    scores = to_safe - References([fail], center).mean_distance(safe[held])[:, 0]
    threshold = torch.quantile(scores, quantile)
    return Calibration(float(threshold), max(float(threshold - scores.median()), 1e-6))

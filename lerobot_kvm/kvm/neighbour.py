"""A skill's energy from the nearest neighbours of its failures (`kvm.risk_model="neighbour"`), on the raw
contexts c_raw.

One failure gives the energy model a few dozen hazardous contexts, and what it learns from them ranks the next
episode's shifted contexts poorly (kvm-check, categories A and B), while the same memories rank them well by
nearest neighbours: how much nearer a context lies to the skill's failure contexts than to its safe ones. What
that difference means is set by the skill's own safe experience: each recorded safe episode is scored as a
held-out one (its own samples left out), and the energy crosses eq. 2's midpoint at the `quantile` of those
scores, rising by `slope` / gamma per spread between their median and that quantile: v = sigmoid(slope) at the
median. A steeper slope keeps more of the safe side near v = 1 and takes more of the hazardous side below tau_v;
it does not change how the skill's contexts rank.

The search runs at every gate-open step, so it is a few tensor operations for all skills at once: squared
distances as |x|^2 - 2 x.y + |y|^2 from one matrix product in the references' own span, every skill's references
padded to the longest with infinitely distant rows.
"""

from dataclasses import dataclass

import torch
from torch import Tensor

NEIGHBOURS = 3
# The energy crosses eq. 2's midpoint at this quantile of the held-out safe scores and rises by the slope per spread
# (kvm-check with slope 10 against 5: docs/measurements.md).
NEIGHBOUR_QUANTILE = 0.95
NEIGHBOUR_SLOPE = 10.0
CALIBRATION_SAMPLES = 512  # held-out safe samples the threshold is taken over


class Span:
    """Coordinates for distances to a fixed set of reference rows: about their mean (which keeps the squared norms
    near their spread, so float32 cancellation in |x|^2 - 2 x.y + |y|^2 stays far below it) and in an orthonormal
    basis of their span. For y in the span, x.y needs only x's projection, and |x|^2 its full norm: raw contexts
    (hundreds of dimensions, most of them the instruction's embedding, which takes a handful of values) are
    searched in a few dozen."""

    def __init__(self, rows: Tensor) -> None:
        self.center = rows.mean(0)
        _, singular, basis = torch.linalg.svd(rows - self.center, full_matrices=False)
        keep = singular > singular[0] * max(rows.shape) * torch.finfo(rows.dtype).eps
        self.basis = basis[keep].T.contiguous()  # [L, r]

    def coords(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(x [B, L] in the span's basis [B, r], its squared distance to the center [B])."""
        x = x - self.center
        return x @ self.basis, torch.linalg.vecdot(x, x)


class References:
    """The reference rows of S sets (one per skill) in one `Span`, padded for one nearest-neighbour search of
    them all."""

    def __init__(self, sets: list[Tensor], span: Span) -> None:
        size = max(len(s) for s in sets)
        first = sets[0]
        self.coords = first.new_zeros(span.basis.shape[1], len(sets), size)  # [r, S, M]
        self.norms = first.new_full((len(sets), size), float("inf"))  # [S, M]: padding lies infinitely far
        for i, s in enumerate(sets):
            coords, norms = span.coords(s)
            self.coords[:, i, : len(s)] = coords.T
            self.norms[i, : len(s)] = norms
        self.coords, self.norms = self.coords.flatten(1), self.norms.flatten()
        self.shape = (len(sets), size)
        self.k = min(NEIGHBOURS, size)
        counts = torch.tensor([min(len(s), self.k) for s in sets], device=first.device)
        self.missing = torch.arange(self.k, device=first.device) >= counts.unsqueeze(-1)  # [S, k]: padding
        self.short = bool(self.missing.any())
        self.counts = counts.to(first.dtype)  # [S]

    def mean_distance(self, coords: Tensor, norms: Tensor, exclude: Tensor | None = None) -> Tensor:
        """[B, S] mean distance of rows x (`Span.coords`: [B, r] and [B]) to their k nearest references in each set
        (`exclude` [B, S, M] bool: references not to count; a set with fewer than k counts those it has)."""
        d2 = torch.addmm(self.norms, coords, self.coords, alpha=-2.0).view(len(coords), *self.shape)
        if exclude is not None:
            d2 = d2.masked_fill(exclude, float("inf"))
        nearest = d2.topk(self.k, largest=False).values.add_(norms.view(-1, 1, 1))
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
    and failure rows (E_c's codes or raw contexts) and calibration."""

    def __init__(
        self, skills: list[int], safe: list[Tensor], fail: list[Tensor], calibrations: list[Calibration], slope: float
    ) -> None:
        device = safe[0].device
        self.span = Span(torch.cat([*safe, *fail]))
        self.skills = torch.tensor(skills, device=device)
        self.references = References([*safe, *fail], self.span)  # safe sets, then failure sets: one search
        threshold = torch.tensor([c.threshold for c in calibrations], device=device)
        scale = slope / torch.tensor([c.width for c in calibrations], device=device)
        # E = (risk - threshold) * scale / gamma - l0 with risk = safe distance - failure distance: one affine map
        # of the 2S distances, W [2S, S] and b [S] (divided by gamma and shifted by l0 on use)
        eye = torch.eye(len(skills), device=device)
        self.weight = torch.cat([eye, -eye]) * scale
        self.bias = -threshold * scale
        self._affine: tuple[float, float, Tensor, Tensor] | None = None

    def energy(self, x: Tensor, gamma: float, l0: float) -> Tensor:
        """[B, S] E such that v (eq. 2) is 1/2 at each threshold and sigmoid(slope) at the held-out safe median."""
        if self._affine is None or self._affine[:2] != (gamma, l0):
            self._affine = (gamma, l0, self.weight / gamma, self.bias / gamma - l0)
        _, _, weight, bias = self._affine
        return torch.addmm(bias, self.references.mean_distance(*self.span.coords(x)), weight)


@torch.no_grad()
def calibrate(safe: Tensor, tags: Tensor, fail: Tensor, quantile: float) -> Calibration | None:
    """The calibration of a skill with safe rows [N, L] (tags [N]: the recorded episode of each, -1 untagged) and
    failure rows [M, L]; None without failures or without two recorded episodes to hold one out against the others."""
    tagged = torch.nonzero(tags >= 0).flatten()
    if not len(fail) or len(torch.unique(tags[tagged])) < 2:
        return None
    generator = torch.Generator().manual_seed(0)  # the same threshold for the same memory
    held = tagged[torch.randperm(len(tagged), generator=generator)[:CALIBRATION_SAMPLES].to(tagged.device)]
    own = (tags[held].unsqueeze(1) == tags.unsqueeze(0)) & (tags >= 0)  # [H, N]: the held-out sample's episode
    span = Span(torch.cat([safe, fail]))
    held_coords = span.coords(safe[held])
    to_safe = References([safe], span).mean_distance(*held_coords, exclude=own.unsqueeze(1))[:, 0]
    scores = to_safe - References([fail], span).mean_distance(*held_coords)[:, 0]
    threshold = torch.quantile(scores, quantile)
    return Calibration(float(threshold), max(float(threshold - scores.median()), 1e-6))

"""A skill's safe experience as the reference a failure of that skill is labelled against.

Before a shift shows, a failed attempt senses what a safe one does: blaming those steps would contradict the safe
memory and suppress the skill where it is still valid. Once the shift shows, the attempt leaves the safe
experience and, in a failure, stays out of it until the end. Both are measured in the unit of the experience's
own spread: how far the safe samples of one recorded episode lie from those of another.
"""

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class SafeExperience:
    """samples [N, D]: a skill's safe samples; spread [M]: each of its samples from a recorded episode, its distance
    to the nearest sample of another recorded episode (empty without two recorded episodes: nothing is known)."""

    samples: Tensor
    spread: Tensor

    def distance(self, c_raw: Tensor) -> Tensor:
        """[T] distance of each context to its nearest safe sample."""
        return torch.cdist(c_raw.to(self.samples), self.samples).min(1).values

    def known(self, c_raw: Tensor, quantile: float) -> Tensor:
        """[T] bool: contexts no further from the safe experience than its ordinary spread (the `quantile` of the
        spread), which a failure cannot be blamed on."""
        if not len(self.spread) or not len(c_raw):
            return torch.zeros(len(c_raw), dtype=torch.bool, device=c_raw.device)
        return self.distance(c_raw) <= torch.quantile(self.spread, quantile)

    def departed(self, c_raw: Tensor, radius: float | None) -> Tensor:
        """[T] bool over an attempt's steps, in order: the steps from which it stays further from the safe
        experience than `radius` times its median spread until its end (all of them if it never comes closer;
        none if it ends close, or where `radius` is None: the rule is off). The spread's upper quantiles, which
        `known` takes, come from the phases where safe episodes differ most (the approach, the first contact); a
        shift that shows at the end of an attempt often stays inside them while it departs from everything the
        skill met at that point."""
        out = torch.zeros(len(c_raw), dtype=torch.bool, device=c_raw.device)
        if radius is None or not len(self.spread) or not len(c_raw):
            return out
        close = torch.nonzero(self.distance(c_raw) <= radius * torch.quantile(self.spread, 0.5)).flatten()
        out[int(close[-1]) + 1 if len(close) else 0 :] = True
        return out

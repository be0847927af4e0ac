"""When the shift shows, and whether a switch of skill then still helps (a hidden shift must show in time to act).

The *envelope* is what the sensed context looks like when the prior skill runs on the prior variant: per control
step and channel the min and max over prior-variant runs, widened in time by `window` steps either side (runs differ
in timing by a few steps: the object's random placement lengthens or shortens the approach), then in value by
`stretch` times the step's own band width (twenty runs' min and max understate where the next run may go) and by
`margin` times the channel's full range over those runs plus `floor` (so that a channel that never moved does not
alarm on numerical noise). A step's bounds come from the runs still going then (a prior run ends on success); a run
longer than all of them is compared with the last step's bounds. Per-step bounds rather than one global band,
because the same force is normal while squeezing and alarming while approaching.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

WINDOW = 3  # control steps either side that a step's bounds also cover
STRETCH = 1.0  # of a step's band width, added on either side
MARGIN = 0.05  # of each channel's full range over the envelope's runs
FLOOR = 1e-3  # added to every bound: sensor units (N, m, rad) well below any effect the shifts cause


@dataclass(frozen=True)
class Envelope:
    """Per-step [low, high] bounds, each [steps, channels], of the prior variant's sensed context."""

    low: np.ndarray
    high: np.ndarray

    @classmethod
    def fit(
        cls,
        runs: list[np.ndarray],
        window: int = WINDOW,
        stretch: float = STRETCH,
        margin: float = MARGIN,
        floor: float = FLOOR,
    ) -> "Envelope":
        """The envelope of `runs`, each [steps, channels] (a run's contexts, the reset's first)."""
        steps = max(len(r) for r in runs)
        padded = np.full((len(runs), steps, runs[0].shape[1]), np.nan)
        for i, r in enumerate(runs):
            padded[i, : len(r)] = r
        low, high = np.nanmin(padded, axis=0), np.nanmax(padded, axis=0)
        spans = [slice(max(0, t - window), t + window + 1) for t in range(steps)]
        low = np.stack([low[s].min(axis=0) for s in spans])
        high = np.stack([high[s].max(axis=0) for s in spans])
        frames = np.concatenate(runs)
        pad = stretch * (high - low) + margin * (frames.max(axis=0) - frames.min(axis=0)) + floor
        return cls(low - pad, high + pad)

    def outside(self, step: int, context: np.ndarray) -> bool:
        """Whether one step's context [channels] lies outside the envelope (past its last step: the last bounds)."""
        row = min(step, len(self.low) - 1)
        return bool(((context < self.low[row]) | (context > self.high[row])).any())

    def exit_step(self, contexts: np.ndarray) -> int | None:
        """First step at which `contexts` ([steps, channels]) leave the envelope; None if they never do."""
        rows = np.minimum(np.arange(len(contexts)), len(self.low) - 1)
        outside = ((contexts < self.low[rows]) | (contexts > self.high[rows])).any(axis=1)
        hits = np.flatnonzero(outside)
        return int(hits[0]) if len(hits) else None


def last_rescue_step(rescues: Callable[[int], bool], harm_step: int, known: dict[int, bool]) -> int | None:
    """Latest takeover step that still rescues the episode, by bisection on [0, `harm_step`).

    Assumes an earlier switch never does worse than a later one. A switch at `harm_step` comes too late by
    definition (the catastrophe ended the episode). `known` holds takeover steps already tried and their outcome.
    None when not even a switch at step 0 rescues.
    """
    known = {**known, harm_step: False}

    def ok(step: int) -> bool:
        if step not in known:
            known[step] = rescues(step)
        return known[step]

    good = [s for s, v in known.items() if v and s < harm_step]
    lo = max(good) if good else 0
    if not good and not ok(0):
        return None
    hi = min(s for s, v in known.items() if not v and s > lo)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo

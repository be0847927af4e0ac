"""95 % intervals for the benchmark's rates, and paired intervals on the difference between two methods.

A benchmark rate is a ratio of counts pooled over cells: one cell is one (run, scenario) of a method, holding
`k` events (solved challenges, catastrophic attempts, ...) out of `n` trials. Runs share the pool but draw
their own seeds, and scenarios differ far more from one another than episodes of one scenario do, so the
trials are not independent: the interval comes from a bootstrap that resamples runs and scenarios (each with
replacement, crossed: every resampled run meets every resampled scenario), not episodes. A single proportion
with no such structure (one run of one scenario) gets Wilson's score interval instead.

Two methods met the same scenarios in runs with the same seeds, so their difference is paired: both are
computed on the same resampled runs and scenarios, and the difference is "detectable" only where its interval
excludes 0.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

Z_95 = 1.959963984540054  # standard normal quantile of 0.975
BOOTSTRAP_SAMPLES = 2000  # percentile-interval ends move by well under a point at this count
Cell = tuple[int, str]  # (run, scenario)
Counts = Mapping[Cell, tuple[int, int]]  # cell -> (events k, trials n)


@dataclass(frozen=True)
class Interval:
    """A rate (or difference of rates) with its 95 % interval; `None` where nothing was counted."""

    value: float | None
    low: float | None
    high: float | None

    def excludes_zero(self) -> bool:
        return self.low is not None and self.high is not None and (self.low > 0 or self.high < 0)

    def as_dict(self) -> dict[str, float | None]:
        return {"value": self.value, "low": self.low, "high": self.high}


EMPTY = Interval(None, None, None)


def wilson(k: int, n: int, z: float = Z_95) -> Interval:
    """Wilson's score interval for k successes in n independent trials."""
    if n == 0:
        return EMPTY
    if not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return Interval(p, max(0.0, centre - half), min(1.0, centre + half))


def newcombe(k1: int, n1: int, k2: int, n2: int) -> Interval:
    """k1/n1 - k2/n2 with Newcombe's hybrid score interval (from both proportions' Wilson intervals).

    Used where a paired difference has nothing to resample (one run of one scenario); it ignores the pairing,
    so it is the wider of the two.
    """
    a, b = wilson(k1, n1), wilson(k2, n2)
    if a.value is None or b.value is None:
        return EMPTY
    diff = a.value - b.value
    low = diff - math.hypot(a.value - a.low, b.high - b.value)
    high = diff + math.hypot(a.high - a.value, b.value - b.low)
    return Interval(diff, low, high)


def _tables(counts: Counts, runs: list[int], scenarios: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(k, n) as run x scenario arrays; a cell a method never met counts 0 of 0."""
    k = np.zeros((len(runs), len(scenarios)))
    n = np.zeros((len(runs), len(scenarios)))
    for (run, scenario), (events, trials) in counts.items():
        k[runs.index(run), scenarios.index(scenario)] = events
        n[runs.index(run), scenarios.index(scenario)] = trials
    return k, n


def _resampled_rates(k: np.ndarray, n: np.ndarray, run_draws: np.ndarray, scenario_draws: np.ndarray) -> np.ndarray:
    """The pooled rate sum(k) / sum(n) of each bootstrap sample (NaN where a sample counted nothing)."""
    # per sample: how often each run and each scenario was drawn; a cell's weight is their product
    run_weights = np.stack([np.bincount(d, minlength=k.shape[0]) for d in run_draws])
    scenario_weights = np.stack([np.bincount(d, minlength=k.shape[1]) for d in scenario_draws])
    events = np.einsum("br,rs,bs->b", run_weights, k, scenario_weights)
    trials = np.einsum("br,rs,bs->b", run_weights, n, scenario_weights)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(trials > 0, events / np.where(trials > 0, trials, 1), np.nan)


def _draws(n_runs: int, n_scenarios: int, samples: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.integers(0, n_runs, (samples, n_runs)), rng.integers(0, n_scenarios, (samples, n_scenarios))


def _percentiles(values: np.ndarray) -> tuple[float | None, float | None]:
    values = values[~np.isnan(values)]
    if values.size == 0:
        return None, None
    low, high = np.quantile(values, [0.025, 0.975])
    return float(low), float(high)


def _cells(*counts: Counts) -> tuple[list[int], list[str]]:
    cells = {cell for c in counts for cell in c}
    return sorted({run for run, _ in cells}), sorted({scenario for _, scenario in cells})


def _pooled(counts: Counts) -> float | None:
    trials = sum(n for _, n in counts.values())
    return sum(k for k, _ in counts.values()) / trials if trials else None


def rate_interval(counts: Counts, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> Interval:
    """The pooled rate over all cells with its bootstrap interval over runs and scenarios.

    One cell alone has nothing to resample: its interval is Wilson's.
    """
    value = _pooled(counts)
    if value is None:
        return EMPTY
    runs, scenarios = _cells(counts)
    if len(runs) == 1 and len(scenarios) == 1:
        return wilson(*next(iter(counts.values())))
    k, n = _tables(counts, runs, scenarios)
    low, high = _percentiles(_resampled_rates(k, n, *_draws(len(runs), len(scenarios), samples, seed)))
    return Interval(value, low, high)


def paired_difference(counts: Counts, reference: Counts, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> Interval:
    """rate(counts) - rate(reference), both resampled on the same runs and scenarios."""
    value, base = _pooled(counts), _pooled(reference)
    if value is None or base is None:
        return EMPTY
    runs, scenarios = _cells(counts, reference)
    if len(runs) == 1 and len(scenarios) == 1:
        return newcombe(*next(iter(counts.values())), *next(iter(reference.values())))
    draws = _draws(len(runs), len(scenarios), samples, seed)
    diff = _resampled_rates(*_tables(counts, runs, scenarios), *draws) - _resampled_rates(
        *_tables(reference, runs, scenarios), *draws
    )
    low, high = _percentiles(diff)
    return Interval(value - base, low, high)

"""Seeded bootstrap confidence intervals for the report's figures.

Percentile intervals (95 %) over ``RESAMPLES`` resamples of the trials, drawn from a generator
seeded with ``SEED`` on every call, so a report is the same each time it is made. Figures over
planning calls resample whole trials (a cluster bootstrap: the calls of one trial are not
independent). Fewer than ``MIN_TRIALS`` values give no interval.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

SEED = 20240613
RESAMPLES = 2000
MIN_TRIALS = 5
LEVEL = 0.95


def _interval(values: np.ndarray) -> tuple[float, float]:
    tail = (1.0 - LEVEL) / 2.0 * 100.0
    low, high = np.percentile(values, [tail, 100.0 - tail])
    return float(low), float(high)


def bootstrap(
    values: Sequence[float], statistic: Callable[[np.ndarray], np.ndarray] | str = "mean"
) -> tuple[float, float] | None:
    """95 % interval of ``statistic`` ("mean" or "median") of ``values``; None below MIN_TRIALS."""
    v = np.asarray([x for x in values if x is not None], dtype=np.float64)
    if v.size < MIN_TRIALS:
        return None
    rng = np.random.default_rng(SEED)
    samples = v[rng.integers(0, v.size, size=(RESAMPLES, v.size))]
    if statistic == "mean":
        stats = samples.mean(axis=1)
    elif statistic == "median":
        stats = np.median(samples, axis=1)
    else:
        stats = statistic(samples)  # type: ignore[operator]
    return _interval(stats)


def bootstrap_pooled(groups: Sequence[Sequence[float]], quantile: float = 50.0) -> tuple[float, float] | None:
    """95 % interval of a quantile of all values pooled, resampling the groups (trials) whole."""
    kept = [np.asarray(g, dtype=np.float64) for g in groups if len(g)]
    if len(kept) < MIN_TRIALS:
        return None
    rng = np.random.default_rng(SEED)
    stats = np.empty(RESAMPLES)
    for b, pick in enumerate(rng.integers(0, len(kept), size=(RESAMPLES, len(kept)))):
        stats[b] = np.percentile(np.concatenate([kept[i] for i in pick]), quantile)
    return _interval(stats)

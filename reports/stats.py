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
CHUNK = 200  # resamples of a pooled quantile computed at once


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
    """95 % interval of a quantile of all values pooled, resampling the groups (trials) whole.

    A resample is the groups drawn, each as often as drawn: the values sorted once, its quantile
    is read off the counts (numpy's default linear interpolation between the ranks on either side,
    the same figure ``np.percentile`` gives on the concatenated resample), ``CHUNK`` resamples at
    once."""
    kept = [np.asarray(g, dtype=np.float64) for g in groups if len(g)]
    if len(kept) < MIN_TRIALS:
        return None
    rng = np.random.default_rng(SEED)
    picks = rng.integers(0, len(kept), size=(RESAMPLES, len(kept)))
    values = np.concatenate(kept)
    owner = np.repeat(np.arange(len(kept)), [len(g) for g in kept])
    order = np.argsort(values, kind="stable")
    values, owner = values[order], owner[order]
    stats = np.empty(RESAMPLES)
    for first in range(0, RESAMPLES, CHUNK):
        pick = picks[first : first + CHUNK]
        rows = len(pick)
        drawn = np.bincount((pick + len(kept) * np.arange(rows)[:, None]).ravel(), minlength=rows * len(kept))
        ranks = np.cumsum(drawn.reshape(rows, len(kept))[:, owner], axis=1)  # values up to each sorted one
        index = quantile / 100.0 * (ranks[:, -1] - 1)
        below = np.floor(index)
        gamma = index - below
        above = np.minimum(below + 1, ranks[:, -1] - 1)
        low = values[(ranks <= below[:, None]).sum(axis=1)]
        high = values[(ranks <= above[:, None]).sum(axis=1)]
        step = high - low
        stats[first : first + rows] = np.where(gamma >= 0.5, high - step * (1 - gamma), low + step * gamma)
    return _interval(stats)

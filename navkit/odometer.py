"""The odometer: metres driven and radians turned by the odometry since a mark.

One piece for every system that asks "how far since ...": NavTopo's navigator (a lost pose is
declared after ``LOST_AFTER_M`` of odometry alone) and start-up (hypotheses confirmed over motion),
its mapping (the pose's covariance grows with the metres), and the metric baseline (a kidnapped
start turns, then explores; a global find is confirmed over turning and motion).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .geometry import between

__all__ = ["Odometer"]


class Odometer:
    """Sums the odometry's steps: ``metres`` (length of the translations) and ``radians`` (absolute
    turning). The first reading only sets the mark."""

    __slots__ = ("metres", "radians", "_last")

    def __init__(self) -> None:
        self.metres = 0.0
        self.radians = 0.0
        self._last: NDArray[np.float64] | None = None

    def update(self, odom: ArrayLike) -> NDArray[np.float64]:
        """Adds the step from the last reading to ``odom`` (x, y, yaw); the step in the last
        reading's frame, zero at the first reading."""
        odom = np.array(odom, dtype=np.float64)
        step = np.zeros(3) if self._last is None else between(self._last, odom)
        self.metres += float(np.hypot(step[0], step[1]))
        self.radians += abs(float(step[2]))
        self._last = odom
        return step

    def restart_from(self, odom: ArrayLike | None) -> None:
        """The next step counts from ``odom`` (None: from the next reading); the sums stay."""
        self._last = None if odom is None else np.array(odom, dtype=np.float64)

    @property
    def last(self) -> NDArray[np.float64] | None:
        """The last reading (None before the first)."""
        return self._last

    @property
    def started(self) -> bool:
        """Whether a reading has come in."""
        return self._last is not None

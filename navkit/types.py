"""Plain data passed between the runner and every navigation system.

These live in ``navtopo`` (the bottom layer) so that systems can use them without importing
the runner; ``runners.systems`` re-exports them with the ``NavigationSystem`` protocol.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Observation:
    """What the robot senses at one tick.

    stamp:  simulation time in seconds.
    points: (N, 3) float32 lidar returns in the robot frame (x forward, y left, z up from the
            floor below the robot centre), floor hits included.
    odom:   (3,) float64 odometry pose [x, y, yaw] in the odometry frame (the first pose of the run).
    """

    stamp: float
    points: NDArray[np.float32]
    odom: NDArray[np.float64]


@dataclass(frozen=True)
class Command:
    """Velocity command of a unicycle robot: linear m/s (forward), angular rad/s (left)."""

    linear: float = 0.0
    angular: float = 0.0


class Status(StrEnum):
    ACTIVE = "active"
    REACHED = "reached"
    FAILED = "failed"


@dataclass
class NavStatus:
    state: Status = Status.ACTIVE
    reason: str = ""


@dataclass
class PlanningStats:
    """Wall-clock durations of the planning calls of one trial, in milliseconds."""

    planning_ms: list[float] = field(default_factory=list)


MEMORY_PARTS = ("map", "localization", "derived", "model")


@dataclass
class MemoryBreakdown:
    """Exact bytes a navigation system holds, split the same way for every system (DESIGN.md,
    "Measurement definitions"). Each figure is an ``nbytes`` sum over the data structures.

    map:          the navigation map as stored (grids, graph structure, poses);
    localization: what is kept to localize (descriptors, prepared grids, distance fields of the map);
    derived:      what is built from the map for planning (eroded masks, union grids);
    model:        learned weights loaded at navigation time.
    """

    map: int = 0
    localization: int = 0
    derived: int = 0
    model: int = 0

    @property
    def total(self) -> int:
        return int(self.map + self.localization + self.derived + self.model)

    def as_dict(self) -> dict[str, int]:
        return {**{part: int(getattr(self, part)) for part in MEMORY_PARTS}, "total": self.total}

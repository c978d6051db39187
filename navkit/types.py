"""Plain data passed between the runner and every navigation system.

These live in ``navkit`` (the bottom layer) so that systems can use them without importing
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


class FailureStage(StrEnum):
    """Where a navigation trial failed: the ``failure_stage`` of its record (docs/DESIGN.md, "Trial end").

    STARTUP:      the start-up localization (NavTopo's hypotheses never committed; the baseline's
                  initial registration or relocalization found no pose on the map), or any ending
                  while the system had not localized yet;
    LOCALIZATION: lost while navigating (tracking fits rejected, odometry only for too long), or
                  ``reached`` declared away from the goal (the system believed it was there);
    GLOBAL_PLAN:  no route to the goal on the whole map (NavTopo's Dijkstra over the graph with no
                  edge removed, the baseline's and the oracle's grid search);
    LOCAL_PLAN:   NavTopo's local planner in the union grid: no local path to the goal in its
                  location, or edges removed (no local path across them) until no route was left;
    FOLLOWER:     following a path: collision, stuck, the simulated-time limit;
    RUNNER:       the trial's process: an exception, a crash, the wall-clock limit, out of memory.
    """

    STARTUP = "startup"
    LOCALIZATION = "localization"
    GLOBAL_PLAN = "global_plan"
    LOCAL_PLAN = "local_plan"
    FOLLOWER = "follower"
    RUNNER = "runner"


@dataclass
class NavStatus:
    """What a system says of its trial, read by the runner after every ``step``.

    state, reason: active, reached, or failed with a reason (``no_path``, ``not_localized``, ...).
    stage: once failed, the stage it failed in (``FailureStage``); while active, the stage it is in
           when that is not following its path (``STARTUP`` until it has localized,
           ``LOCALIZATION`` while it has lost its pose), else None. The runner gives an ending it
           decides itself (collision, stuck, the time limit) to that stage, else to ``FOLLOWER``.
    detail: one line in the system's words: where it failed (which location or edge, plan from
            and to, how far from the goal); while active, what it is doing (kept current at its
            plans and looks, so that an ending the runner decides says it too). None: nothing to say.
    """

    state: Status = Status.ACTIVE
    reason: str = ""
    stage: FailureStage | None = None
    detail: str | None = None


@dataclass
class PlanningStats:
    """Wall-clock durations of the planning calls of one trial, in milliseconds."""

    planning_ms: list[float] = field(default_factory=list)


MEMORY_PARTS = ("map", "localization", "derived", "model")

# Every system that declares "reached" by its own estimate does so within this of the goal (nav2's
# default xy_goal_tolerance); the runner's STOP rule is 0.5 m on the true pose, so the 0.25 m between
# is room for the system's map to sit off the world frame (a map-frame goal converted through a
# drifting map; BENCHMARKS.md, "Design choices: the stop tolerance").
STOP_TOLERANCE_M = 0.25


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

"""Obstacles the metric map lacks, as the baseline sees them while it navigates (DESIGN.md).

A return of the scan's obstacle band within ``new_obstacle_range`` that lies farther than
``new_obstacle_distance`` from every mapped wall (the scan-to-map distance field,
``localization.ScanToMap``) is a new obstacle: a door closed since mapping, a box, a person. The
latest scan's new obstacles decide whether the path ahead is blocked (``PathFollower.
path_ahead_blocked``); all of them are remembered, and blocked for the planner, until the lidar
sees through them (``navkit.obstacles.ObstacleMemory``, a costmap's marking and clearing).

Points: scans (N, 2) in the robot frame; new obstacles (M, 2) in the map frame; poses map-frame
``[x, y, yaw]``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit.obstacles import ObstacleMemory

from .config import PlanningConfig
from .localization import ScanToMap


class UnmappedObstacles:
    """The new obstacles of the latest scan, and every one remembered until seen through."""

    def __init__(self, config: PlanningConfig) -> None:
        self.config = config
        self.memory = ObstacleMemory()  # returns the map lacks, map frame, until seen through
        self.latest: NDArray[np.float64] = np.zeros((0, 2))

    @property
    def points(self) -> NDArray[np.float64]:
        """(N, 2) the remembered new obstacles, map frame."""
        return self.memory.points

    @property
    def nbytes(self) -> int:
        return self.memory.nbytes

    def clear(self) -> None:
        """Forget the remembered obstacles (a new goal)."""
        self.memory.clear()

    def reset(self) -> None:
        """Forget everything (a new trial)."""
        self.memory.clear()
        self.latest = np.zeros((0, 2))

    def update(self, pose: NDArray, points: NDArray, walls: ScanToMap | None, rays: NDArray | None = None) -> None:
        """Mark the returns (N, 2, robot frame) that the map does not explain (far from every mapped
        wall of ``walls`` at ``pose``); clear the marked ones this scan sees through, judged by
        ``rays`` (M, 2+, robot frame: every return of the band; ``points`` if None). A voxel-filtered
        scan keeps one return in 0.1-0.2 m of a near wall, so most 1° directions along it have none
        and looked open: a shut door behind a corner was forgotten as the robot turned away from it,
        and the robot drove back and forth between the two ways round (a generated changed world)."""
        cfg = self.config
        self.latest = np.zeros((0, 2))
        if walls is None:
            return
        near = points[np.hypot(points[:, 0], points[:, 1]) <= cfg.new_obstacle_range]
        if len(near):
            world = se2.transform_points(pose, near.astype(np.float64))
            self.latest = world[walls.sample(world)[0] > cfg.new_obstacle_distance]
        self.memory.update(pose, points if rays is None else rays, self.latest, cfg.new_obstacle_range)

"""Anchors: the true poses (scenario frame) where a graph system made its locations.

A graph system (NavTopo) estimates its pose relative to a location, named by the stamp of the
scan it was made from, never in a global frame. The mapping stage records the true pose of each
location's scan (``MappingReport.anchors``: ``[[stamp, x, y, yaw], ...]``); with them the runner
places those location-relative estimates in the scenario frame to measure their error, gives
goals in the paper's location-relative form (``--goals native``), and checks start-up
localizations and goal conversions. The system itself never sees them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit import grid_search


@dataclass
class Anchors:
    """The true poses (scenario frame) where a graph system made its locations, by creation stamp:
    the runner turns the system's location-relative estimates into checkable ones with them."""

    poses: dict[float, NDArray[np.float64]]

    @classmethod
    def from_rows(cls, rows: list[list[float]] | None) -> Anchors | None:
        if not rows:
            return None
        return cls({round(float(r[0]), 6): np.asarray(r[1:4], dtype=np.float64) for r in rows})

    def locate(self, anchored: tuple[float, NDArray] | None) -> NDArray[np.float64] | None:
        """(anchor stamp, pose in the anchor) -> the pose in the scenario frame, or None."""
        if anchored is None:
            return None
        anchor = self.poses.get(round(float(anchored[0]), 6))
        return None if anchor is None else se2.compose(anchor, np.asarray(anchored[1], dtype=np.float64))

    def goal_form(self, goal: NDArray, world: Any) -> tuple[float, NDArray[np.float64]]:
        """The goal (2,) in the paper's form: the creation stamp of the location nearest to it with a
        clear line of sight in the ground-truth free space (else the nearest), and the goal in that
        location's frame."""
        stamps = list(self.poses)
        poses = np.array([self.poses[s] for s in stamps])
        order = np.argsort(np.hypot(*(poses[:, :2] - goal).T))
        chosen = int(order[0])
        goal_cell = world.to_cell(goal)
        for k in order[:20]:
            cell = world.to_cell(poses[k, :2])
            if world.inside(cell) and world.inside(goal_cell) and grid_search.line_of_sight(world.free, cell, goal_cell):
                chosen = int(k)
                break
        return stamps[chosen], se2.transform_points(se2.inverse(poses[chosen]), np.asarray(goal, float)[None, :2])[0]

    def judge(self, stats: dict[str, Any], goal: NDArray) -> dict[str, Any]:
        """The system's goal conversion against the truth (diagnostics)."""
        out: dict[str, Any] = {}
        goal_estimate = stats.get("goal")
        if goal_estimate:
            anchor = self.poses.get(round(float(goal_estimate["vertex_stamp"]), 6))
            if anchor is not None:
                point = se2.transform_points(anchor, np.asarray(goal_estimate["pose"], dtype=np.float64)[None, :2])[0]
                out["goal_conversion_error_m"] = round(float(np.hypot(*(point - goal))), 4)
        return out

"""Planning a path between two metric points on an occupancy raster: the one function every grid
planner of the benchmark calls (the oracle on the ground-truth raster, the metric baseline on its
global grid, NavTopo's local planner on its union grid, and the scenario's route and trial legs).

``plan_path`` tries a list of passable masks in order (e.g. free space eroded by the robot radius
plus a margin, then by the radius alone, then with unknown cells counted as free); on each it snaps
the start and the goal to the nearest passable cell within ``snap_cells`` (a robot a few
centimetres inside an inflated zone still gets a path), searches with Lazy Theta*
(``navkit.grid_search``), and returns the first path found as metric points with the exact start
and goal at its ends. A snapped end cell more than a cell and a half from its exact point stays on
the path, as the way into the planned free space.

Raster convention (``navkit.grid_search``): ``mask[row, col]``, row ↔ y, col ↔ x, the centre of
cell (r, c) at ``origin + ((c + 0.5) * resolution, (r + 0.5) * resolution)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit import grid_search
from navkit.raster import GridFrame


@dataclass(frozen=True)
class PlannedPath:
    points: NDArray[np.float64]  # (K, 2) metric, exact start first and exact goal last
    level: int  # index of the mask the path was found on (0: the first, most cautious one)

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.points, axis=0).T).sum()) if len(self.points) > 1 else 0.0


def plan_path(
    masks: Sequence[NDArray[np.bool_]] | Callable[[int], NDArray[np.bool_]],
    frame: GridFrame,
    start_xy: ArrayLike,
    goal_xy: ArrayLike,
    snap_cells: int = 0,
    levels: int | None = None,
    exact_goal: bool = True,
) -> PlannedPath | None:
    """The first path found on ``masks`` in order (see the module docstring), or None.

    masks: passable (H, W) bool rasters, or a callable giving the i-th one on demand (a caller that
    builds its fallbacks only when needed), then with ``levels`` their number.
    exact_goal: end at ``goal_xy`` itself (default); False ends at the free cell the goal snapped
    to, for a goal the robot does not fit at (a goal estimated off into a wall is approached, never
    driven into).
    """
    start_xy = np.asarray(start_xy, dtype=np.float64)[:2]
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    start_cell = frame.to_cell(start_xy)
    goal_cell = frame.to_cell(goal_xy)
    count = levels if callable(masks) else len(masks)
    for level in range(count or 0):
        passable = masks(level) if callable(masks) else masks[level]
        start = grid_search.nearest_free(passable, start_cell, snap_cells)
        goal = grid_search.nearest_free(passable, goal_cell, snap_cells)
        if start is None or goal is None:
            continue
        cells = grid_search.theta_star(passable, start, goal)
        if cells is None:
            continue
        end_xy = goal_xy if exact_goal else frame.to_world(cells[-1:])[0]
        return PlannedPath(waypoints(frame, cells, start_xy, end_xy), level)
    return None


def waypoints(frame: GridFrame, cells: NDArray, start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64]:
    """A cell path as metric points with the exact start and goal at its ends; an end cell more than
    a cell and a half from its exact point stays, as the way into the planned free space."""
    points = frame.to_world(cells)
    near = 1.5 * frame.resolution
    head = points[1:] if np.hypot(*(points[0] - start_xy)) <= near else points
    if len(head) and np.hypot(*(head[-1] - goal_xy)) <= near:
        head = head[:-1]
    return np.vstack([start_xy[None], head, goal_xy[None]])

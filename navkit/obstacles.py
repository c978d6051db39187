"""Obstacles the map lacks, remembered until the lidar sees through them: the marking and clearing
of a costmap's obstacle layer (as Nav2's), shared by every system that plans on a map.

A return of the scan's obstacle band that no mapped wall explains is *marked* (kept as a point on a
grid of ``resolution``); a marked point is *cleared* when a later scan's ray in its direction reaches
beyond it. So a closed door stays blocked while the robot drives round the other way (it never sees
through it), and a person who walked away is forgotten as soon as the robot looks there again.

Points are 2D in the frame the caller plans in (the metric map, or a NavTopo location); the robot's
pose is given in that frame; scans are (N, 2+) in the robot frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from navkit.geometry import inverse, transform_points
from navkit.raster import GridFrame

BINS = 360


def _bins(xy: NDArray) -> NDArray[np.int64]:
    """The 1° azimuth bin of each point (N, 2+) of the robot frame."""
    return (np.floor((np.arctan2(xy[:, 1], xy[:, 0]) + np.pi) / (2 * np.pi) * BINS).astype(np.int64)) % BINS


class ObstacleMemory:
    """Marked obstacle points, cleared by rays that pass them."""

    def __init__(self, resolution: float = 0.1, clear_margin: float = 0.3, max_points: int = 20000) -> None:
        self.resolution = resolution
        self.clear_margin = clear_margin
        self.max_points = max_points
        self.clear()

    def clear(self) -> None:
        self._cells = np.zeros((0, 2), dtype=np.int64)

    def __len__(self) -> int:
        return len(self._cells)

    @property
    def frame(self) -> GridFrame:
        """The cells' frame: the planning frame's origin is the corner of cell (0, 0)."""
        return GridFrame(np.zeros(2), self.resolution)

    @property
    def points(self) -> NDArray[np.float64]:
        """(N, 2) the marked points (cell centres) in the planning frame."""
        return self.frame.to_world(self._cells[:, ::-1])

    @property
    def nbytes(self) -> int:
        return int(self._cells.nbytes)

    def update(self, pose: NDArray, scan_xy: NDArray, new_xy: NDArray, max_range: float) -> None:
        """Clear what this scan sees through, then mark its unexplained returns.

        pose: (3,) the robot in the planning frame; scan_xy: (N, 2+) the scan's obstacle returns in
        the robot frame; new_xy: (M, 2) the returns the map does not explain, planning frame;
        max_range: directions without a return are seen through up to this far.
        """
        if len(self._cells):
            self._cells = self._cells[~self._seen_through(pose, np.asarray(scan_xy)[:, :2], max_range)]
        self.mark(new_xy)

    def mark(self, xy: NDArray) -> None:
        """Mark points (M, 2+) of the planning frame."""
        if len(xy):
            cells = self.frame.to_cell(np.asarray(xy, dtype=np.float64)[:, :2])[:, ::-1]  # kept as [x, y] cells
            self._cells = np.unique(np.vstack([self._cells, cells]), axis=0)[-self.max_points :]

    def _seen_through(self, pose: NDArray, scan_xy: NDArray, max_range: float) -> NDArray[np.bool_]:
        """Which marked points lie in front of this scan's first return in their direction."""
        local = transform_points(inverse(pose), self.points)
        distance = np.hypot(local[:, 0], local[:, 1])
        first = np.full(BINS, max_range)
        if len(scan_xy):
            ranges = np.hypot(scan_xy[:, 0], scan_xy[:, 1])
            scan_bins = (
                np.floor((np.arctan2(scan_xy[:, 1], scan_xy[:, 0]) + np.pi) / (2 * np.pi) * BINS).astype(np.int64)
            ) % BINS
            np.minimum.at(first, scan_bins, ranges)
        # a point is seen through when the rays of its bin and both neighbours all reach beyond it
        reach = np.minimum(np.minimum(first, np.roll(first, 1)), np.roll(first, -1))
        return (distance + self.clear_margin < reach[_bins(local)]) & (distance < max_range - self.clear_margin)

    def transform(self, pose: NDArray) -> None:
        """Re-express the points in a new frame: ``pose`` is the new frame's origin in the old one."""
        if len(self._cells):
            moved = transform_points(inverse(pose), self.points)
            self._cells = np.unique(self.frame.to_cell(moved)[:, ::-1], axis=0)
